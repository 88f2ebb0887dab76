"""A worker process of the certified oracle (minirt.oracles.exact.render.Workers): ``python -m
minirt.oracles.exact.worker`` reads batches of pixels from its standard input and writes their certified
values to its standard output, each message an 8-byte little-endian length and a pickle, until its input
closes.

Its own interpreter, started afresh: not a fork of minirt (with Dr.Jit's and the renderers' threads in
it), and not a multiprocessing child, which imports the caller's main script again -- a user's script
without a ``__main__`` guard would run once more in every worker. Pickles come only from the minirt
process that started it, through its pipe. What the model's code prints goes to standard error: standard
output is the channel.
"""

from __future__ import annotations

import os
import pickle
import signal
import sys

from minirt.oracles.exact.channel import read_message, write_message


def serve() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # minirt decides (it is in a session of its own anyway)
    channel = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    from minirt.oracles.exact.render import run_batch

    source = sys.stdin.buffer
    while True:
        data = read_message(source)
        if data is None:
            return
        try:
            answer = ("ok", run_batch(pickle.loads(data)))
        except Exception as e:  # the batch's failure, said to the caller, which makes it the render's ERROR
            answer = ("error", f"{type(e).__name__}: {(str(e).splitlines() or [''])[0]}")
        write_message(channel, pickle.dumps(answer, protocol=pickle.HIGHEST_PROTOCOL))


if __name__ == "__main__":
    serve()
