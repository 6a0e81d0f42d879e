"""A scenario spec resolved once against its files: :class:`ScenarioSource`.

Whether the configuration is a converted WOMD scene (its log is the traffic) and the [begin, end]
of a SUMO configuration's run are worked out here once and handed down: to the nominal pass
(:func:`coster_sumo.pipeline.scenario.nominal_scene`), the variants' injection passes
(:mod:`coster_sumo.sim.inject`) and the proof of the escapes (:mod:`coster_sumo.avoidability.proof`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from coster_sumo.core.spec import ScenarioSpec
from coster_sumo.errors import InputError, not_found
from coster_sumo.formats.scene_folder import converted_scene_file
from coster_sumo.formats.sumocfg import config_files, read_sumocfg

DEFAULT_DURATION_S = 60.0  # [s] recorded when neither --end nor the configuration bounds the run


def simulation_window(spec: ScenarioSpec) -> tuple[float, float]:
    """[begin, end] [s] of a SUMO configuration's run: the spec's, else the configuration's.

    Both are absolute simulation times as SUMO reads them (a configuration may begin at 57600 s);
    without any end the run lasts :data:`DEFAULT_DURATION_S`. An end not after the begin is one
    :class:`InputError` line.
    """
    cfg = read_sumocfg(spec.config)
    begin = spec.begin if spec.begin is not None else (cfg.begin or 0.0)
    end = spec.end if spec.end is not None else cfg.end
    if end is None:
        end = begin + DEFAULT_DURATION_S
    if end <= begin:
        raise InputError(f"{spec.config}: end {end:g} s is not after begin {begin:g} s (SUMO's end is an absolute "
                         "time; --duration gives a length from the begin)")
    return begin, end


@dataclass(frozen=True)
class ScenarioSource:
    """A scenario spec resolved once: what is converted or not, and the window, are not worked out
    again by every step that needs them.

    Attributes:
        spec: the scenario spec.
        log: the converted WOMD scene's log (``scene.npz``), None for any other SUMO configuration.
        window: [begin, end] [s] of a SUMO configuration's run (:func:`simulation_window`); None for
            a converted scene (its log is its window).
        inputs: the configuration and the files it names (an output folder must hold none of them).
    """

    spec: ScenarioSpec
    log: Path | None
    window: tuple[float, float] | None
    inputs: tuple[Path, ...] = ()

    @property
    def converted(self) -> bool:
        """Whether it is a converted WOMD scene (the log is the traffic)."""
        return self.log is not None

    @classmethod
    def of(cls, scenario: ScenarioSpec | ScenarioSource) -> ScenarioSource:
        """``scenario`` itself where it is resolved already, else :meth:`resolve` of it."""
        return scenario if isinstance(scenario, ScenarioSource) else cls.resolve(scenario)

    @classmethod
    def resolve(cls, spec: ScenarioSpec) -> ScenarioSource:
        """The source of ``spec``; a missing configuration or a bad window is one :class:`InputError` line."""
        if not spec.config.exists():
            raise not_found(spec.config)
        log = converted_scene_file(spec.config)
        return cls(spec, log, None if log is not None else simulation_window(spec), tuple(config_files(spec.config)))
