"""What a recording holds: its topics and schemas, and the Foxglove messages of one step (map, scene, step, log)."""

from __future__ import annotations

import base64
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from smorphi_rl.coverage import CoverageResult, path_points_m
from smorphi_rl.env_config import MAX_MOVE_SIZES
from smorphi_rl.errors import SmorphiError
from smorphi_rl.geometry import Morphology, block_corners, block_poses
from smorphi_rl.maps import Cell, Map

TOPIC_STEP, TOPIC_MAP, TOPIC_SCENE, TOPIC_LOG = "/smorphi/step", "/map", "/morphology", "/log"
OUR_TOPICS = (TOPIC_STEP, TOPIC_MAP, TOPIC_SCENE, TOPIC_LOG)
FRAME = "map"
STEP_PERIOD_NS = 100_000_000
"""Steps are 0.1 s apart on a recording's clock, so Foxglove plays an episode at 10 steps a second."""
METADATA_NAME = "smorphi_rl"
LOG_ENDED, LOG_CUT = "episode end after", "cut short"
"""How the last /log line of an episode begins: it ran to its end (terminated, or its step limit), or the env was
reset or closed before (a run that ended mid-episode)."""
SUFFIX, PART_SUFFIX = ".mcap", ".mcap.part"
MCAP_MAGIC = b"\x89MCAP0\r\n"
SCHEMA_DIR = Path(__file__).resolve().parents[1] / "schemas"
OCCUPANCY = {Cell.FREE: 0, Cell.OCCUPIED: 100, Cell.UNKNOWN: 255}
"""Grid cell values in the recorded foxglove.Grid (free 0, occupied 100, unknown 255, as in ROS maps)."""
BLOCK_RGBA = ((0.12, 0.47, 0.71, 0.9), (1.0, 0.5, 0.05, 0.9), (0.17, 0.63, 0.17, 0.9), (0.58, 0.4, 0.74, 0.9))
BLOCK_HEIGHT_M = 0.02
JSON_SEPARATORS = (",", ":")
PATH_PLACEHOLDER = "@coverage-path@"
PATH_CACHE_SIZE = 2048
MAX_MOVE = 2 * MAX_MOVE_SIZES
"""The largest move index a step can record: a hinge picks one of 2 K + 1 moves, K step sizes (env `moves`)."""

ACTED = ("action", "reward", "R2")
"""A step's fields that step 0, the reset state, has none of: it leaves them out (Foxglove's schema reader takes
one type a field, never ["number", "null"])."""
STEP_SCHEMA: dict[str, Any] = {
    "title": "smorphi_rl.Step",
    "description": "One env step of a morphology-design episode (step 0 is the reset state: no action, reward or R2)",
    "type": "object",
    "properties": {
        "step": {"type": "integer", "minimum": 0},
        "theta": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3},
        "action": {"type": "array", "items": {"type": "integer", "minimum": 0, "maximum": MAX_MOVE}},
        "reward": {"type": "number", "description": "the env's reward, in the run's reward mode"},
        "R1": {"type": "number", "description": "w1 * P_c - w2 * P_len"},
        "R2": {"type": "number", "description": "reward - R1: under reward `paper` the paper's R2, -beta "
               "when the action left the shape unchanged, else 0"},
        "P_c": {"type": "number"},
        "P_len": {"type": "integer"},
        "coverage_free_pct": {"type": "number"},
        "feasible": {"type": "boolean"},
        "map": {"type": "string"},
    },
    "required": ["step", "theta", "R1", "P_c", "P_len", "coverage_free_pct", "feasible", "map"],
}  # fmt: skip


class RecordingError(SmorphiError):
    """A recording that cannot be used (not MCAP, none of our channels, nothing recoverable)."""


def _stamp(ns: int) -> dict[str, int]:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _quaternion_z(yaw_rad: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw_rad / 2), "w": math.cos(yaw_rad / 2)}


def grid_message(grid_map: Map, ns: int) -> dict[str, Any]:
    """The map as a foxglove.Grid: one UINT8 `occupancy` field, row 0 at the map origin (lowest y)."""
    lut = np.zeros(3, dtype=np.uint8)
    for cell, value in OCCUPANCY.items():
        lut[cell] = value
    w = grid_map.cells.shape[1]
    x, y, _ = grid_map.origin  # its yaw ignored, as the plans ignore it: rotated, the grid left the path
    return {
        "timestamp": _stamp(ns),
        "frame_id": FRAME,
        "pose": {"position": {"x": float(x), "y": float(y), "z": 0.0}, "orientation": _quaternion_z(0.0)},
        "column_count": int(w),
        "cell_size": {"x": grid_map.resolution_m, "y": grid_map.resolution_m},
        "row_stride": int(w),
        "cell_stride": 1,
        "fields": [{"name": "occupancy", "offset": 0, "type": 1}],
        "data": base64.b64encode(lut[grid_map.cells].tobytes()).decode("ascii"),
    }


def robot_offset(plan: CoverageResult, grid_map: Map) -> tuple[float, float]:
    """Where the footprint's lower-left corner sits: the first tile of the coverage path (else the map origin)."""
    x0, y0 = float(grid_map.origin[0]), float(grid_map.origin[1])
    if not (plan.feasible and plan.placements is not None and len(plan.placements)):
        return x0, y0
    row, col = (int(v) for v in plan.placements[0])
    r = grid_map.resolution_m
    return x0 + col * r, y0 + row * r


def _entity(entity_id: str, ns: int, theta: tuple[float, ...], **primitives: list[Any]) -> dict[str, Any]:
    entity: dict[str, Any] = {"timestamp": _stamp(ns), "frame_id": FRAME, "id": entity_id,
                              "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": False,
                              "metadata": [{"key": "theta", "value": json.dumps(list(theta))}]}  # fmt: skip
    for kind in ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models"):
        entity[kind] = primitives.get(kind, [])
    return entity


def path_line(plan: CoverageResult, grid_map: Map) -> dict[str, Any] | None:
    """The coverage path as a foxglove LinePrimitive (LINE_STRIP); None for an infeasible shape."""
    if not (plan.feasible and plan.placements is not None and len(plan.placements)):
        return None
    pts = np.round(path_points_m(plan, grid_map), 4).tolist()
    return {
        "type": 0, "pose": {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": _quaternion_z(0.0)},
        "thickness": 0.02, "scale_invariant": False, "points": [{"x": x, "y": y, "z": 0.005} for x, y in pts],
        "color": {"r": 0.84, "g": 0.15, "b": 0.16, "a": 1.0}, "colors": [], "indices": [],
    }  # fmt: skip


def scene_message(theta: tuple[float, float, float], plan: CoverageResult, grid_map: Map, block_side_m: float,
                  ns: int, lines: list[Any] | None = None) -> dict[str, Any]:  # fmt: skip
    """A foxglove.SceneUpdate: the four blocks as cubes at the start of the path, and the coverage path
    (`lines`, when given, replaces the path's LinePrimitive list: the recorder passes a cached one)."""
    morphology = Morphology.of(theta)
    poses = block_poses(morphology, block_side_m)
    corners = [block_corners(p, block_side_m) for p in poses]
    ox, oy = robot_offset(plan, grid_map)
    dx = ox - min(x for c in corners for x, _ in c)
    dy = oy - min(y for c in corners for _, y in c)
    cubes = []
    for pose, c, rgba in zip(poses, corners, BLOCK_RGBA, strict=True):
        cx, cy = sum(x for x, _ in c) / 4 + dx, sum(y for _, y in c) / 4 + dy
        cubes.append({
            "pose": {"position": {"x": round(cx, 5), "y": round(cy, 5), "z": BLOCK_HEIGHT_M / 2},
                     "orientation": _quaternion_z(math.radians(pose.heading_deg))},
            "size": {"x": block_side_m, "y": block_side_m, "z": BLOCK_HEIGHT_M},
            "color": dict(zip("rgba", rgba, strict=True)),
        })  # fmt: skip
    if lines is None:
        line = path_line(plan, grid_map)
        lines = [] if line is None else [line]
    entities = [_entity("robot", ns, theta, cubes=cubes), _entity("coverage_path", ns, theta, lines=lines)]
    return {"deletions": [], "entities": entities}


def log_message(text: str, ns: int, level: int = 2) -> dict[str, Any]:
    """A foxglove.Log line (INFO by default)."""
    return {"timestamp": _stamp(ns), "level": level, "message": text, "name": "smorphi-rl", "file": "", "line": 0}


def step_record(step: int, info: dict[str, Any], action: Any = None, reward: float | None = None) -> dict[str, Any]:
    """The /smorphi/step message of one step, from the env's info (step 0, the reset state, without `ACTED`)."""
    r1 = float(info["R1"])
    acted = {} if reward is None else {"action": [int(a) for a in np.asarray(action).ravel()],
                                       "reward": float(reward), "R2": float(reward) - r1}  # fmt: skip
    return {
        "step": step,
        "theta": [float(t) for t in info["theta"]],
        **acted,
        "R1": r1,
        "P_c": float(info["P_c"]),
        "P_len": int(info["P_len"]),
        "coverage_free_pct": float(info["coverage_free_pct"]),
        "feasible": bool(info["feasible"]),
        "map": str(info["map"]),
    }


def foxglove_schema(name: str) -> bytes:
    """The JSON schema of a Foxglove message type, as shipped in recording/schemas/."""
    return (SCHEMA_DIR / f"{name}.json").read_bytes()
