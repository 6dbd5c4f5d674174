"""The static maps as candidates of a diagnosis (:mod:`agents.twin.static_map`), beside the catalogue's effects."""

from __future__ import annotations

from dataclasses import replace

from agents.twin.candidates import Candidate, CandidatePlan
from agents.twin.model import GreyFit
from agents.twin.records import Batch
from agents.twin.static_map import MAP_NAMES, map_options

__all__ = ["map_candidates", "with_map_candidates"]


def map_candidates(data: Batch, current: GreyFit) -> list[Candidate]:
    """An input map and an output map with the breakpoints of ``data`` (:func:`agents.twin.static_map.map_options`),
    each unless ``current`` has it already; fitted as an effect is, from the identity (and the one-way map)."""
    return [Candidate(name, (map_options(name, data),)) for name in MAP_NAMES if name not in current.spec.effect_names]


def with_map_candidates(plan: CandidatePlan, data: Batch, current: GreyFit) -> CandidatePlan:
    """``plan`` with :func:`map_candidates` after the catalogue's effects."""
    return replace(plan, candidates=[*plan.candidates, *map_candidates(data, current)])
