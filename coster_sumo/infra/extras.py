"""The optional extras of the package, and the one-line error a command that needs a missing one gives.

A plain ``pip install coster-sumo`` runs every command but these: ``policy`` (extra ``rl``:
gymnasium, stable-baselines3), ``--executor ray`` (``ray``), the OpenSCENARIO exports
(``openscenario``). Nothing else imports them; the modules that do, do so inside the functions
that need them, after :func:`require`.
"""

from __future__ import annotations

import importlib.util

from coster_sumo.errors import InputError

EXTRAS = {"rl": ("gymnasium", "stable_baselines3"), "ray": ("ray",),
          "openscenario": ("scenariogeneration", "xmlschema")}


def missing(extra: str) -> list[str]:
    """The modules of ``extra`` that are not installed."""
    return [m for m in EXTRAS[extra] if importlib.util.find_spec(m) is None]


def require(extra: str, what: str) -> None:
    """Raise :class:`InputError` (one line: what needs which extra, and the pip line) when a module
    of ``extra`` is not installed."""
    gone = missing(extra)
    if gone:
        raise InputError(f"{what} needs the optional extra '{extra}' ({', '.join(gone)} not installed): "
                         f"pip install 'coster-sumo[{extra}]'")
