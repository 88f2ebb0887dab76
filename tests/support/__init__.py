"""Helpers the tests share: a plain transcription of the pseudo-code, student images, the CLI in-process, evidence."""
