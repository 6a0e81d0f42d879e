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
