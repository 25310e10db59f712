"""Episodes recorded to MCAP with Foxglove's schemas, and read back for `replay`. The only module that imports mcap.

`RecordingWrapper` wraps the env inside each env runner and writes every Nth episode of its env
instance to its own file (names carry the worker index and a random instance id, since RLlib's
sub-envs share one EnvContext). A file is written as NAME.mcap.part, flushed after the episode
start, every `flush_steps` steps and at the end, and renamed to NAME.mcap when finished: a file cut
short by a killed worker keeps every flushed chunk, and `read_episode` recovers them.
"""

from __future__ import annotations

import base64
import json
import math
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from smorphi_rl.coverage import CoverageResult, path_points_m
from smorphi_rl.env import MorphologyEnv
from smorphi_rl.errors import SmorphiError
from smorphi_rl.geometry import Morphology, block_corners, block_poses
from smorphi_rl.maps import Cell, Map

TOPIC_STEP, TOPIC_MAP, TOPIC_SCENE, TOPIC_LOG = "/smorphi/step", "/map", "/morphology", "/log"
OUR_TOPICS = (TOPIC_STEP, TOPIC_MAP, TOPIC_SCENE, TOPIC_LOG)
FRAME = "map"
STEP_PERIOD_NS = 100_000_000
"""Steps are 0.1 s apart on a recording's clock, so Foxglove plays an episode at 10 steps a second."""
METADATA_NAME = "smorphi_rl"
SUFFIX, PART_SUFFIX = ".mcap", ".mcap.part"
MCAP_MAGIC = b"\x89MCAP0\r\n"
SCHEMA_DIR = Path(__file__).resolve().parent / "schemas"
OCCUPANCY = {Cell.FREE: 0, Cell.OCCUPIED: 100, Cell.UNKNOWN: 255}
"""Grid cell values in the recorded foxglove.Grid (free 0, occupied 100, unknown 255, as in ROS maps)."""
BLOCK_RGBA = ((0.12, 0.47, 0.71, 0.9), (1.0, 0.5, 0.05, 0.9), (0.17, 0.63, 0.17, 0.9), (0.58, 0.4, 0.74, 0.9))
BLOCK_HEIGHT_M = 0.02
JSON_SEPARATORS = (",", ":")
PATH_PLACEHOLDER = "@coverage-path@"
PATH_CACHE_SIZE = 2048
STEP_SCHEMA: dict[str, Any] = {
    "title": "smorphi_rl.Step",
    "description": "One env step of a morphology-design episode (step 0 is the reset state: no action or reward)",
    "type": "object",
    "properties": {
        "step": {"type": "integer", "minimum": 0},
        "theta": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3},
        "action": {"type": ["array", "null"], "items": {"type": "integer", "minimum": 0, "maximum": 2}},
        "reward": {"type": ["number", "null"], "description": "R1 + R2"},
        "R1": {"type": "number", "description": "w1 * P_c - w2 * P_len"},
        "R2": {"type": ["number", "null"], "description": "-beta when the action left the shape unchanged, else 0"},
        "P_c": {"type": "number"},
        "P_len": {"type": "integer"},
        "coverage_free_pct": {"type": "number"},
        "feasible": {"type": "boolean"},
        "map": {"type": "string"},
    },
    "required": ["step", "theta", "action", "reward", "R1", "R2", "P_c", "P_len", "coverage_free_pct", "feasible",
                 "map"],
}  # fmt: skip


class RecordingError(SmorphiError):
    """A recording that cannot be used (not MCAP, none of our channels, nothing recoverable)."""


@dataclass(frozen=True)
class RecordingConfig:
    """Where and how often the env runners record: every `every`-th episode of each env instance."""

    directory: str
    every: int
    flush_steps: int = 50
    metadata: dict[str, str] = field(default_factory=dict)
    """Run-level facts stored in every file: run name, algorithm, seed, configuration."""

    def __post_init__(self) -> None:
        for name in ("every", "flush_steps"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise RecordingError(f"recording '{name}' must be a positive integer, got {value!r}")
        if not Path(self.directory).is_absolute():
            raise RecordingError(f"recording directory must be absolute (env runners run elsewhere): {self.directory}")

    def to_dict(self) -> dict[str, Any]:
        return {"directory": self.directory, "every": self.every, "flush_steps": self.flush_steps,
                "metadata": dict(self.metadata)}  # fmt: skip


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
    x, y, yaw = grid_map.origin
    return {
        "timestamp": _stamp(ns),
        "frame_id": FRAME,
        "pose": {"position": {"x": float(x), "y": float(y), "z": 0.0}, "orientation": _quaternion_z(float(yaw))},
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
    """The /smorphi/step message of one step, from the env's info (step 0: the reset state)."""
    r1 = float(info["R1"])
    return {
        "step": step,
        "theta": [float(t) for t in info["theta"]],
        "action": None if action is None else [int(a) for a in np.asarray(action).ravel()],
        "reward": None if reward is None else float(reward),
        "R1": r1,
        "R2": None if reward is None else float(reward) - r1,
        "P_c": float(info["P_c"]),
        "P_len": int(info["P_len"]),
        "coverage_free_pct": float(info["coverage_free_pct"]),
        "feasible": bool(info["feasible"]),
        "map": str(info["map"]),
    }


class EpisodeWriter:
    """One episode's MCAP file, crash-safe: NAME.mcap.part until `finish` renames it to NAME.mcap."""

    def __init__(self, path: Path, metadata: dict[str, str], flush_steps: int) -> None:
        from mcap.writer import CompressionType, Writer

        self.final = path
        self.part = path.with_name(path.name.removesuffix(SUFFIX) + PART_SUFFIX)
        self.part.parent.mkdir(parents=True, exist_ok=True)
        self._fh = self.part.open("wb")
        self._writer = Writer(self._fh, compression=CompressionType.ZSTD)
        self._writer.start(profile="", library="smorphi-rl")
        self._channels: dict[str, int] = {}
        for topic, name, schema in ((TOPIC_STEP, "smorphi_rl.Step", json.dumps(STEP_SCHEMA).encode()),
                                    (TOPIC_MAP, "foxglove.Grid", _foxglove_schema("Grid")),
                                    (TOPIC_SCENE, "foxglove.SceneUpdate", _foxglove_schema("SceneUpdate")),
                                    (TOPIC_LOG, "foxglove.Log", _foxglove_schema("Log"))):  # fmt: skip
            schema_id = self._writer.register_schema(name=name, encoding="jsonschema", data=schema)
            self._channels[topic] = self._writer.register_channel(topic, message_encoding="json", schema_id=schema_id)
        self._writer.add_metadata(METADATA_NAME, {k: str(v) for k, v in metadata.items()})
        self.flush_steps = flush_steps
        self.steps = 0

    def write(self, topic: str, message: dict[str, Any] | bytes, ns: int) -> None:
        """One message, a dict (JSON-encoded here) or JSON already encoded."""
        data = message if isinstance(message, bytes) else json.dumps(message, separators=JSON_SEPARATORS).encode()
        ns = int(ns)  # a float or negative log_time corrupts the whole file (the notes)
        self._writer.add_message(self._channels[topic], log_time=ns, publish_time=ns, data=data)

    def end_step(self) -> None:
        """Count a step; flush the chunk every `flush_steps` steps."""
        self.steps += 1
        if self.steps % self.flush_steps == 0:
            self.flush()

    def flush(self) -> None:
        self._writer.flush()
        self._fh.flush()

    def finish(self) -> Path:
        """Write the summary, close and rename to NAME.mcap."""
        self._writer.finish()
        self._fh.close()
        self.part.replace(self.final)
        return self.final


def _foxglove_schema(name: str) -> bytes:
    return (SCHEMA_DIR / f"{name}.json").read_bytes()


class RecordingWrapper(gym.Wrapper):
    """Records every `config.every`-th episode of this env instance to its own MCAP file."""

    def __init__(self, env: MorphologyEnv, config: RecordingConfig, worker_index: int = 0) -> None:
        super().__init__(env)
        self.config = config
        self.worker_index = worker_index
        self.instance = uuid.uuid4().hex[:8]
        self.episodes = 0
        self._writer: EpisodeWriter | None = None
        self._t0 = 0
        self._step = 0
        self._paths: dict[int, tuple[Any, bytes]] = {}
        """Encoded LinePrimitive of each plan's path, keyed by the plan's (cached, shared) path array."""

    @property
    def morph_env(self) -> MorphologyEnv:
        return self.env.unwrapped  # type: ignore[return-value]

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        self._end("cut short by a reset")
        obs, info = self.env.reset(seed=seed, options=options)
        episode = self.episodes
        self.episodes += 1
        if episode % self.config.every == 0:
            self._start(episode, seed, info)
        return obs, info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, raw_reward, terminated, truncated, info = self.env.step(action)
        reward = float(raw_reward)
        if self._writer is not None:
            self._step += 1
            self._write_step(step_record(self._step, info, action, reward))
            if terminated or truncated:
                best = f"({', '.join(f'{t:g}' for t in info['best_theta'])}) R1 {info['best_R1']:.2f}"
                self._end(f"episode end after {self._step} steps ({'terminated' if terminated else 'truncated'}); "
                          f"best {best}")  # fmt: skip
        return obs, reward, terminated, truncated, info

    def close(self) -> None:
        self._end("cut short: the env was closed")
        super().close()

    def _start(self, episode: int, seed: int | None, info: dict[str, Any]) -> None:
        env = self.morph_env
        name = f"episode-w{self.worker_index:02d}-{self.instance}-{episode:05d}{SUFFIX}"
        metadata = dict(self.config.metadata) | {
            "map": env.grid_map.name, "worker": str(self.worker_index), "env_instance": self.instance,
            "episode": str(episode), "reset_seed": "none" if seed is None else str(seed),
            "env_config": json.dumps(env.config.to_dict()), "start_theta": json.dumps(list(info["theta"])),
        }  # fmt: skip
        self._writer = EpisodeWriter(Path(self.config.directory) / name, metadata, self.config.flush_steps)
        self._t0 = time.time_ns()
        self._step = 0
        self._writer.write(TOPIC_MAP, grid_message(env.grid_map, self._t0), self._t0)
        theta = ", ".join(f"{t:g}" for t in info["theta"])
        self._writer.write(TOPIC_LOG, log_message(f"episode {episode} start on {env.grid_map.name} at ({theta})",
                                                  self._t0), self._t0)  # fmt: skip
        self._write_step(step_record(0, info))
        self._writer.flush()

    def _write_step(self, record: dict[str, Any]) -> None:
        assert self._writer is not None
        env = self.morph_env
        ns = self._t0 + record["step"] * STEP_PERIOD_NS
        theta = tuple(record["theta"])
        plan = env.plan(theta)  # type: ignore[arg-type]
        path = self._path_json(plan)
        scene = scene_message(theta, plan, env.grid_map, env.config.block_side_m, ns,  # type: ignore[arg-type]
                              lines=[PATH_PLACEHOLDER] if path else [])  # fmt: skip
        data = json.dumps(scene, separators=JSON_SEPARATORS).encode()
        self._writer.write(TOPIC_STEP, record, ns)
        self._writer.write(TOPIC_SCENE, data.replace(b'"' + PATH_PLACEHOLDER.encode() + b'"', path), ns)
        self._writer.end_step()

    def _path_json(self, plan: CoverageResult) -> bytes:
        """The path's LinePrimitive as JSON, encoded once per footprint (b"" when there is no path)."""
        key = id(plan.path_tiles)
        hit = self._paths.get(key)
        if hit is not None and hit[0] is plan.path_tiles:
            return hit[1]
        line = path_line(plan, self.morph_env.grid_map)
        encoded = b"" if line is None else json.dumps(line, separators=JSON_SEPARATORS).encode()
        if len(self._paths) >= PATH_CACHE_SIZE:
            self._paths.clear()
        self._paths[key] = (plan.path_tiles, encoded)  # holding the array keeps its id unique
        return encoded

    def _end(self, text: str) -> None:
        if self._writer is None:
            return
        ns = self._t0 + self._step * STEP_PERIOD_NS
        self._writer.write(TOPIC_LOG, log_message(text, ns), ns)
        self._writer.finish()
        self._writer = None


# -- reading -------------------------------------------------------------------------------------


@dataclass
class Episode:
    """What one recorded file holds: its metadata, every step and scene, the map, the log lines."""

    path: Path
    metadata: dict[str, str]
    steps: list[dict[str, Any]]
    scenes: list[dict[str, Any]]
    grid: dict[str, Any] | None
    logs: list[str]
    truncated: bool

    @property
    def best(self) -> dict[str, Any] | None:
        """The step with the highest R1 (the first, on ties)."""
        return max(self.steps, key=lambda s: s["R1"], default=None)

    def grid_cells(self) -> np.ndarray | None:
        """The recorded map as Cell values, row 0 at the lowest y."""
        if self.grid is None:
            return None
        raw = np.frombuffer(base64.b64decode(self.grid["data"]), dtype=np.uint8)
        cells = np.full(raw.shape, Cell.UNKNOWN, dtype=np.uint8)
        for cell, value in OCCUPANCY.items():
            cells[raw == value] = cell
        return cells.reshape(-1, self.grid["column_count"])

    def grid_map(self) -> Map:
        """The recorded map as a Map (for drawing the episode); an error when its message was not recovered."""
        cells = self.grid_cells()
        if cells is None or self.grid is None:
            raise RecordingError(f"{self.path}: the map message was not recovered; nothing to draw on")
        pos = self.grid["pose"]["position"]
        return Map(cells, float(self.grid["cell_size"]["x"]), (pos["x"], pos["y"], 0.0), self.steps[0]["map"])

    def changed_steps(self, max_frames: int) -> list[int]:
        """Indices of the steps where the shape changed (and the first), thinned evenly to at most `max_frames`."""
        changed = [i for i in range(len(self.steps)) if i == 0 or self.steps[i]["theta"] != self.steps[i - 1]["theta"]]
        if len(changed) > max_frames:
            changed = [changed[round(k)] for k in np.linspace(0, len(changed) - 1, max_frames)]
        return changed

    def frame(self, index: int) -> dict[str, Any]:
        """Step `index` as plain values for a figure: blocks (x, y, yaw rad, side) and the path as (N, 2) metres."""
        entities = {e["id"]: e for e in self.scenes[index]["entities"]}
        blocks = []
        for cube in entities["robot"]["cubes"]:
            q = cube["pose"]["orientation"]
            pos = cube["pose"]["position"]
            blocks.append((pos["x"], pos["y"], 2 * math.atan2(q["z"], q["w"]), cube["size"]["x"]))
        pts = [[p["x"], p["y"]] for line in entities["coverage_path"]["lines"] for p in line["points"]]
        return {"blocks": blocks, "path": np.asarray(pts, dtype=float).reshape(-1, 2), "step": self.steps[index]}

    @property
    def episode_return(self) -> float:
        return float(sum(s["reward"] for s in self.steps if s["reward"] is not None))


def read_episode(path: str | Path) -> Episode:
    """Read a recording, complete or cut short (every complete chunk is recovered; `truncated` says so)."""
    from mcap.records import Channel, Footer, Message, Metadata
    from mcap.stream_reader import StreamReader

    file = Path(path)
    try:
        with file.open("rb") as fh:
            if fh.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
                raise RecordingError(f"{path}: not an MCAP file")
    except FileNotFoundError:
        raise RecordingError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise RecordingError(f"{path}: is a directory") from None
    topics: dict[int, str] = {}
    meta: dict[str, str] = {}
    by_topic: dict[str, list[dict[str, Any]]] = {t: [] for t in OUR_TOPICS}
    complete = False
    with file.open("rb") as fh:
        try:
            for record in StreamReader(fh).records:
                if isinstance(record, Channel):
                    topics[record.id] = record.topic
                elif isinstance(record, Message) and topics.get(record.channel_id) in by_topic:
                    by_topic[topics[record.channel_id]].append(json.loads(record.data))
                elif isinstance(record, Metadata) and record.name == METADATA_NAME:
                    meta = dict(record.metadata)
                elif isinstance(record, Footer):
                    complete = True
        except Exception:  # a cut-short file ends in a partial record: keep what came before it
            complete = False
    if not topics or not any(t in OUR_TOPICS for t in topics.values()):
        cut = not complete and not topics
        what = "is cut short before any channel" if cut else "holds none of smorphi-rl's channels"
        raise RecordingError(f"{path}: {what} ({', '.join(OUR_TOPICS)})")
    steps = by_topic[TOPIC_STEP]
    if not steps:
        raise RecordingError(f"{path}: no step could be recovered" + ("" if complete else " (the file is cut short)"))
    required = STEP_SCHEMA["required"]
    for i, st in enumerate(steps):  # a step another writer made, or damaged: named, never a KeyError later
        missing = [k for k in required if k not in st] if isinstance(st, dict) else required
        if missing:
            raise RecordingError(f"{path}: step message {i} lacks {', '.join(missing[:3])} (not a smorphi-rl step)")
    scenes = by_topic[TOPIC_SCENE][: len(steps)]
    steps = steps[: len(scenes)] if len(scenes) < len(steps) else steps
    grid = by_topic[TOPIC_MAP][0] if by_topic[TOPIC_MAP] else None
    return Episode(file, meta, steps, scenes, grid, [m["message"] for m in by_topic[TOPIC_LOG]], not complete)


def episode_files(directory: str | Path) -> list[Path]:
    """Every recording under `directory` (finished and .part), in name order."""
    root = Path(directory)
    return sorted(p for p in root.rglob("*") if p.is_file() and p.name.endswith((SUFFIX, PART_SUFFIX)))
