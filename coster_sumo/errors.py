"""Exceptions that the CLI turns into one clear line and an exit code (see docs/method.md, Contracts)."""

from __future__ import annotations


class CosterError(Exception):
    """Base class: the message is one line naming the file or object and what is wrong."""

    exit_code = 1


class InputError(CosterError):
    """Bad input (file, record, option) detected before or while reading it: exit code 2."""

    exit_code = 2


class SumoError(CosterError):
    """SUMO is missing, failed to start, or died."""

    exit_code = 1


class NoSnapshot(CosterError):
    """The scene yields no collision snapshot; the message says why.

    ``t_index``: the 2 Hz step of the collision time that had no acceptable placement, when one
    was chosen (another collision time may still have one); None when the scene has none at all.
    """

    def __init__(self, message: str, t_index: int | None = None) -> None:
        super().__init__(message)
        self.t_index = t_index


def not_found(path: object, kind: str = "file", referenced_by: object = None, why: str | None = None
              ) -> InputError:
    """The one wording of a missing input, for every command: ``PATH: no such file`` (``kind``:
    file, folder, or "file or folder"), then ``(referenced by CFG)`` where another file names it,
    or ``(why)``: what the file is and how to get it."""
    via = f" (referenced by {referenced_by})" if referenced_by is not None else f" ({why})" if why else ""
    return InputError(f"{path}: no such {kind}{via}")


def one_line(text: str) -> str:
    """``text`` as one printable line: newlines and other control characters escaped.

    Messages name things read from input files (ids, keys); a crafted id must not be able to break
    the one-line-per-error contract or write terminal control sequences.
    """
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in str(text))
