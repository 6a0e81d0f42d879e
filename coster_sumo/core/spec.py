"""What to generate: one scenario spec (which simulation, which target) and one generation config
(which methods, how many samples and variants). Plain data, shared by ``run``, ``regress``,
``eval scenarios`` and the Python API; the generation core (:mod:`coster_sumo.method.generation`)
takes both. Besides them, what a run's avoidability labels are stated for (:class:`LabelOptions`)
and how its variants are injected (:class:`InjectionSettings`), each checked or settled once.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from coster_sumo.errors import InputError

# the adversary classes of ``--adversary`` (their limits: coster_sumo.method.vru.classes)
ADVERSARY_CHOICES = ("vehicle", "cyclist", "pedestrian", "any")


@dataclass(frozen=True)
class ScenarioSpec:
    """One scene: a SUMO configuration, its seed and time window, and the target.

    Attributes:
        config: the ``.sumocfg`` (a converted WOMD scene or any SUMO configuration).
        seed: SUMO's ``--seed``, and with the scene's id the seed of every random choice of the
            generation (``method.generation.generation_rng``: scenes run with one seed do not draw alike).
        begin, end: [s] the recorded window (None: the configuration's own).
        target: the target vehicle id (None: the SDC of a converted scene, else ``ego``).
    """

    config: Path
    seed: int = 0
    begin: float | None = None
    end: float | None = None
    target: str | None = None

    def label(self) -> str:
        """``CFG@seed=N[,begin=S][,end=S][,target=ID]``, the source syntax that gives this spec back."""
        parts = [f"seed={self.seed}"]
        if self.begin is not None:
            parts.append(f"begin={self.begin:g}")
        if self.end is not None:
            parts.append(f"end={self.end:g}")
        if self.target is not None:
            parts.append(f"target={self.target}")
        return f"{self.config}@{','.join(parts)}"

    def to_dict(self) -> dict[str, Any]:
        return {"config": str(self.config), "seed": self.seed, "begin": self.begin, "end": self.end,
                "target": self.target}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ScenarioSpec:
        return cls(Path(d["config"]), int(d.get("seed", 0)), d.get("begin"), d.get("end"), d.get("target"))


@dataclass(frozen=True)
class GenerationConfig:
    """How to generate adversaries (the method choices live in registries, see :mod:`coster_sumo.method`).

    Attributes:
        init: snapshot init, a key of :data:`coster_sumo.method.snapshot.SNAPSHOT_INITS`.
        collision_time: a key of :data:`coster_sumo.method.collision_time.COLLISION_TIME_RULES`.
        rollout: a key of :data:`coster_sumo.rollout.methods.ROLLOUTS`.
        samples: trajectories oversampled per snapshot.
        variants: representatives kept (K-means K).
        models_dir: folder with the weights (None: the shipped ones).
        adversary: the adversary's class, ``vehicle`` (default), ``cyclist``, ``pedestrian`` or ``any``
            (each draw picks one: :mod:`coster_sumo.method.vru.methods`).
    """

    init: str = "snapshot"
    collision_time: str = "entropy"
    rollout: str = "cvae"
    samples: int = 1000
    variants: int = 5
    models_dir: Path | None = None
    adversary: str = "vehicle"

    def __post_init__(self) -> None:
        """The counts, checked when made. The method names and the weights they need are checked against
        the registries (:func:`coster_sumo.method.generation.check_generation`), which sit above this layer
        and take new methods at run time."""
        if self.variants < 1:
            raise InputError(f"--variants must be >= 1, not {self.variants}")
        if self.samples < 1:
            raise InputError(f"--samples must be >= 1, not {self.samples}")
        if self.adversary not in ADVERSARY_CHOICES:
            raise InputError(f"--adversary must be one of {', '.join(ADVERSARY_CHOICES)}, not {self.adversary!r}")

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["models_dir"] = str(self.models_dir) if self.models_dir is not None else None
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> GenerationConfig:
        models = d.get("models_dir")
        return cls(init=str(d.get("init", "snapshot")), collision_time=str(d.get("collision_time", "entropy")),
                   rollout=str(d.get("rollout", "cvae")), samples=int(d.get("samples", 1000)),
                   variants=int(d.get("variants", 5)), models_dir=Path(models) if models else None,
                   adversary=str(d.get("adversary", "vehicle")))


# ----------------------------------------------------------------------------- labels
# the options of the avoidability labels (docs/method.md step 8), checked before any work starts

AVOIDABLE_CHOICES = ("any", "only")


def check_avoidable(choice: str) -> None:
    """``--avoidable``: any (default) or only."""
    if choice not in AVOIDABLE_CHOICES:
        raise InputError(f"--avoidable must be one of {', '.join(AVOIDABLE_CHOICES)}, not {choice!r}")


def check_reaction_time(seconds: float) -> None:
    if not 0.0 <= seconds <= 5.0:
        raise InputError(f"--reaction-time must be between 0 and 5 s, not {seconds:g}")


@dataclass(frozen=True)
class LabelOptions:
    """What the avoidability labels of a run are stated for, checked when made (one
    :class:`InputError` line for a bad one).

    Attributes:
        reaction_time: [s] the reaction time each variant's avoidable / unavoidable label is for.
        avoidable: any (keep every variant) or only (keep the avoidable ones, drawing more).
    """

    reaction_time: float = 1.0
    avoidable: str = "any"

    def __post_init__(self) -> None:
        check_avoidable(self.avoidable)
        check_reaction_time(self.reaction_time)


@dataclass(frozen=True)
class InjectionSettings:
    """How the variants of a run are injected (:func:`coster_sumo.sim.inject.inject_variants`),
    settled once where the run's options are made (:class:`coster_sumo.pipeline.run.RunOptions`).

    Attributes:
        planner: who drives the target (see ``coster-sumo run --planner``), already chosen.
        traci: a TraCI socket instead of libsumo.
        workers: variants run at a time from held copies of the nominal pass.
        timeout: [s] wall clock per variant's pass (None: no limit).
        traffic: ``log`` (a converted scene's agents replay their log) or ``reactive`` (each follows its
            log until the target's deviation reaches it, then SUMO drives it: :mod:`coster_sumo.sim.reactive`);
            a SUMO configuration's own traffic runs in SUMO either way.
        workdir: where a planner writes the files its passes load (its vTypes; None: the current folder).
    """

    planner: str
    traci: bool = False
    workers: int = 1
    timeout: float | None = None
    traffic: str = "log"
    workdir: Path | None = None
