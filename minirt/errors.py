"""Errors a user can act on. The CLI prints them as one line each and exits with status 2."""


class MinirtError(Exception):
    """Bad input or a missing dependency: a message for a person, never a traceback."""

    def __init__(self, *lines: str):
        super().__init__("\n".join(lines))
        self.lines = list(lines)


class SceneError(MinirtError):
    """A scene file that cannot be loaded; one line per problem, each naming file and key."""
