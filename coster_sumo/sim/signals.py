"""The signal states of a recording: SUMO's link states on the map's lanes.

Signals (SUMO link state letters -> :class:`SignalState`):

====================  ===================  =====================================================
SUMO letter           meaning              ours
====================  ===================  =====================================================
``G``, ``g``          green (major/minor)  GO
``y``, ``Y``          yellow               CAUTION
``r``, ``R``, ``u``   red, red-yellow      STOP
``s``                 stop, then go        FLASHING_STOP (a right turn on red)
``o``                 off, blinking        FLASHING_CAUTION
``O``                 off, no signal       UNKNOWN
====================  ===================  =====================================================

Controlled lanes: each link (connection) of a traffic light has one internal ``via`` lane inside
the junction, which carries **exactly** that link's state (like WOMD, whose signal lanes start at
the stop line). The incoming lane that ends at the stop line usually has several links (left,
straight, right) with different states; it gets the **most permissive** of them (order GO >
FLASHING_CAUTION > CAUTION > FLASHING_STOP > STOP > UNKNOWN), so a vehicle waiting on it sees
"go" as soon as any of its movements may go. Pass ``incoming_lanes=False`` to record only the
internal lanes. Nets without internal lanes only have the incoming lanes. Stop points: the start
of the internal lane, the end of the incoming lane (both are the stop line).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from coster_sumo.core.scene import SignalState
from coster_sumo.formats.sumo_net import SumoNet
from coster_sumo.sim.session import SumoSession

# SUMO link state letter -> SignalState (see the module docstring)
LINK_STATE: dict[str, SignalState] = {
    "G": SignalState.GO, "g": SignalState.GO,
    "y": SignalState.CAUTION, "Y": SignalState.CAUTION,
    "r": SignalState.STOP, "R": SignalState.STOP, "u": SignalState.STOP,
    "s": SignalState.FLASHING_STOP,
    "o": SignalState.FLASHING_CAUTION,
    "O": SignalState.UNKNOWN,
}
# How permissive each state is, for lanes with several links (higher = more permissive).
_PERMISSIVE_ORDER = [SignalState.UNKNOWN, SignalState.STOP, SignalState.ARROW_STOP,
                     SignalState.FLASHING_STOP, SignalState.CAUTION, SignalState.ARROW_CAUTION,
                     SignalState.FLASHING_CAUTION, SignalState.GO, SignalState.ARROW_GO]
_RANK_TO_STATE = np.array([int(s) for s in _PERMISSIVE_ORDER], np.int8)
_CHAR_TO_RANK = np.zeros(256, np.int8)  # unknown letters -> rank 0 = UNKNOWN
for _ch, _st in LINK_STATE.items():
    _CHAR_TO_RANK[ord(_ch)] = _PERMISSIVE_ORDER.index(_st)


def link_state_to_signal(state: str) -> np.ndarray:
    """(len(state),) int8 :class:`SignalState` of each letter of a red-yellow-green string."""
    ranks = _CHAR_TO_RANK[np.frombuffer(state.encode("ascii", "replace"), np.uint8)]
    return _RANK_TO_STATE[ranks]


@dataclass(frozen=True, slots=True)
class SignalTable:
    """Where each traffic-light link's state goes in ``SignalStates``.

    Attributes:
        lane_index: (num_controlled,) int64 map lane index of each controlled lane.
        stop_point: (num_controlled, 2) float64 [m].
        tls_ids: (num_links,) str traffic light of each link.
        link_index: (num_links,) int64 position in that light's state string.
        slot: (num_links,) int64 controlled-lane row that the link feeds.
        tls_order: the traffic lights in the order their state strings are concatenated.
        tls_num_links: link count of each light in ``tls_order`` (its state string length).
        flat_link: (num_links,) int64 position of each link in the concatenated state strings.
    """

    lane_index: np.ndarray
    stop_point: np.ndarray
    tls_ids: np.ndarray
    link_index: np.ndarray
    slot: np.ndarray
    tls_order: tuple[str, ...]
    tls_num_links: tuple[int, ...]
    flat_link: np.ndarray

    @classmethod
    def build(cls, net: SumoNet, incoming_lanes: bool = True) -> SignalTable:
        lanes = net.road_map.lanes
        index = {str(lane_id): i for i, lane_id in enumerate(lanes.ids)}
        shapes = lanes.centerline
        slots: dict[int, int] = {}
        lane_index: list[int] = []
        stop: list[np.ndarray] = []
        tls_ids: list[str] = []
        link_index: list[int] = []
        link_slot: list[int] = []

        def slot_of(lane: int, point: np.ndarray) -> int:
            if lane not in slots:
                slots[lane] = len(lane_index)
                lane_index.append(lane)
                stop.append(point)
            return slots[lane]

        for tls, links in sorted(net.signal_links.items()):
            for link in links:
                targets = []
                via = index.get(link.via_lane) if link.via_lane else None
                if via is not None and len(shapes[via]):
                    targets.append(slot_of(via, shapes[via][0]))
                frm = index.get(link.from_lane)
                if frm is not None and len(shapes[frm]) and (incoming_lanes or not link.via_lane):
                    targets.append(slot_of(frm, shapes[frm][-1]))
                for s in targets:
                    tls_ids.append(tls)
                    link_index.append(link.link_index)
                    link_slot.append(s)
        order = sorted(net.signal_links)
        sizes = [max((s.link_index for s in net.signal_links[t]), default=-1) + 1 for t in order]
        start = dict(zip(order, np.cumsum([0, *sizes])[:-1].tolist(), strict=True))
        return cls(lane_index=np.array(lane_index, np.int64),
                   stop_point=np.array(stop, np.float64).reshape(-1, 2),
                   tls_ids=np.array(tls_ids, dtype=str), link_index=np.array(link_index, np.int64),
                   slot=np.array(link_slot, np.int64), tls_order=tuple(order), tls_num_links=tuple(sizes),
                   flat_link=np.array([start[t] for t in tls_ids], np.int64) + np.array(link_index, np.int64))

    def states(self, tls_states: dict[str, str]) -> np.ndarray:
        """(num_controlled,) int8 SignalState of every controlled lane for one step."""
        rank = np.zeros(len(self.lane_index), np.int8)
        if len(self.slot) == 0:
            return rank
        # all state strings side by side, each padded / cut to its link count ("O" = no signal)
        text = "".join(tls_states.get(t, "")[:n].ljust(n, "O")
                       for t, n in zip(self.tls_order, self.tls_num_links, strict=True))
        codes = _CHAR_TO_RANK[np.frombuffer(text.encode("ascii", "replace"), np.uint8)]
        np.maximum.at(rank, self.slot, codes[self.flat_link])
        return _RANK_TO_STATE[rank]


class SignalReader:
    """The signal states of the controlled lanes at each recorded step. Lights change every few
    seconds, so a step whose state strings equal the last step's shares its row (the same values:
    a city pass records 14,000 steps, and mapping each one's strings cost 0.7 s of A10KW's pass)."""

    def __init__(self, session: SumoSession, table: SignalTable) -> None:
        self.session, self.table = session, table
        self.last: dict[str, str] | None = None
        self.row = np.zeros(0, np.int8)

    def read(self) -> np.ndarray:
        """(num_controlled,) int8 :class:`SignalState` of every controlled lane now."""
        if not len(self.table.lane_index):
            return self.row
        now = self.session.tls_states()
        if now != self.last:
            self.last, self.row = now, self.table.states(now)
        return self.row
