"""The viewer's choices, as names (no heavy imports: `lmjx view --help` lists them)."""

from __future__ import annotations

# The per-edge quantities an edge can be coloured by: dataset in /edges, label, unit.
QUANTITIES = {
    "duration": ("duration", "duration", "s"),
    "peak torque ratio": ("peak_torque_ratio", "peak |tau| / tau_max", ""),
    "min manipulability": ("min_manipulability", "min manipulability", ""),
}
DRAWINGS = ("interaction-point paths", "arm swept along")  # how a selected cell's edges are drawn
LABEL_SETS = ("smoothed", "raw")  # the reach map's labels shown
SHOWN = ("NPM + PM", "PM only")  # the cells shown
