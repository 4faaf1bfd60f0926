"""The planner's turned edges (`turned_over_target`, `TurnedEdges`): the map's edges turned
about the arm's base joint, defined in `lmjx.mapfile.turned` (where the public API's
`MapFile.edges_over` and `MapFile.edge` offer the same copies) and named here for the
planner's modules."""

from lmjx.mapfile.turned import (
    START_CLEAR,
    TURN_STEP_DEG,
    TURNS_PER_EDGE,
    TurnAxis,
    TurnedEdges,
    turn_axis,
    turn_xy,
    turned_over_target,
)

__all__ = [
    "START_CLEAR",
    "TURNS_PER_EDGE",
    "TURN_STEP_DEG",
    "TurnAxis",
    "TurnedEdges",
    "turn_axis",
    "turn_xy",
    "turned_over_target",
]
