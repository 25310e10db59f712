"""Reading recordings back for `replay`: complete or cut short, every flushed chunk recovered."""

from __future__ import annotations

import base64
import io
import json
import math
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from smorphi_rl.env_config import MAX_EPISODE_STEPS, MAX_MOVE_SIZES, PLANNING_KEYS, EnvConfig
from smorphi_rl.errors import SmorphiError
from smorphi_rl.geometry import Morphology
from smorphi_rl.inputs import check_not_special, is_finite_number
from smorphi_rl.maps import MAX_ORIGIN_M, MAX_RESOLUTION_M, MIN_RESOLUTION_M, Cell, Map
from smorphi_rl.recording.messages import (
    ACTED,
    LOG_CUT,
    LOG_ENDED,
    MAX_MOVE,
    MCAP_MAGIC,
    METADATA_NAME,
    OCCUPANCY,
    OUR_TOPICS,
    PART_SUFFIX,
    STEP_SCHEMA,
    SUFFIX,
    TOPIC_LOG,
    TOPIC_MAP,
    TOPIC_SCENE,
    TOPIC_STEP,
    RecordingError,
)
from smorphi_rl.score import MAX_P_LEN

FILE_CUT_SHORT = "file cut short"
"""`Episode.cut_short` of a file that ends before its episode did (a killed worker's), the env's own note aside."""


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
    def ended(self) -> bool:
        """Whether the episode ran to its end, as its last log line says (a file cut short after it lost its index
        only)."""
        return bool(self.logs) and self.logs[-1].startswith(LOG_ENDED)

    @property
    def cut_short(self) -> str | None:
        """Why the recording stops before its episode's end: the env was reset or closed mid-episode (a run that
        ended), or the file was cut short; None when the episode ran to its end."""
        if self.logs and self.logs[-1].startswith(LOG_CUT):
            return self.logs[-1]
        return None if self.ended or not self.truncated else FILE_CUT_SHORT

    @property
    def best(self) -> dict[str, Any] | None:
        """The step with the highest R1 (the first, on ties)."""
        return max(self.steps, key=lambda s: s["R1"], default=None)

    def _damaged(self, what: str, exc: Exception) -> RecordingError:
        """One line naming the damaged message and what reading it raised."""
        return RecordingError(f"{self.path}: {what} is damaged ({type(exc).__name__}: {str(exc)[:80]})")

    def grid_cells(self) -> np.ndarray | None:
        """The recorded map as Cell values, row 0 at the lowest y; a damaged map message is named."""
        if self.grid is None:
            return None
        try:
            raw = np.frombuffer(base64.b64decode(self.grid["data"], validate=True), dtype=np.uint8)
            columns = self.grid["column_count"]
            if type(columns) is not int or columns < 1 or raw.size == 0 or raw.size % columns:
                raise ValueError(f"{raw.size} cells in rows of {columns!r}")
        except (KeyError, TypeError, ValueError) as exc:  # binascii.Error is a ValueError
            raise self._damaged("the map message", exc) from None
        cells = np.full(raw.shape, Cell.UNKNOWN, dtype=np.uint8)
        for cell, value in OCCUPANCY.items():
            cells[raw == value] = cell
        return cells.reshape(-1, columns)

    def grid_map(self) -> Map:
        """The recorded map as a Map (for drawing the episode); an error when its message was not recovered."""
        cells = self.grid_cells()
        if cells is None or self.grid is None:
            raise RecordingError(f"{self.path}: the map message was not recovered; nothing to draw on")
        try:
            pos = self.grid["pose"]["position"]
            origin = (float(pos["x"]), float(pos["y"]), 0.0)
            cell = float(self.grid["cell_size"]["x"])
            if not (MIN_RESOLUTION_M <= cell <= MAX_RESOLUTION_M and all(abs(v) <= MAX_ORIGIN_M for v in origin)):
                raise ValueError(f"a cell of {cell:.3g} m at ({origin[0]:.3g}, {origin[1]:.3g}) m, beyond a map file's")
            return Map(cells, cell, origin, self.steps[0]["map"])
        except (KeyError, TypeError, ValueError, OverflowError, SmorphiError) as exc:  # Overflow: a 400-digit integer
            raise self._damaged("the map message", exc) from None

    def covered(self, indices: list[int], grid_map: Map) -> list[np.ndarray | None]:
        """The cells each step's shape covers, planned again on the recorded map with the recording's own planner
        (its `env_config`); None for a step whose plan does not give the recorded P_c and P_len (another planner's
        recording) or where the recording names no usable planner: a replay draws no area it cannot vouch for."""
        try:
            raw = json.loads(self.metadata["env_config"])
            raw = {key: raw[key] for key in PLANNING_KEYS if key in raw}  # all a plan reads: other keys may differ
            evaluator = EnvConfig.from_dict(raw).planning.evaluator(grid_map, cache=False)
        except (KeyError, TypeError, ValueError, AttributeError, RecursionError, SmorphiError):
            return [None] * len(indices)
        found: list[np.ndarray | None] = []
        for index in indices:
            step = self.steps[index]
            try:
                plan = evaluator.plan(Morphology(*step["theta"]))
            except SmorphiError:  # a start the recorded map does not hold, say
                plan = None
            same = plan is not None and plan.P_len == step["P_len"] and math.isclose(plan.P_c, step["P_c"])
            found.append(plan.covered if same and plan is not None else None)
        return found

    def changed_steps(self, max_frames: int) -> list[int]:
        """Indices of the steps where the shape changed (and the first), thinned evenly to at most `max_frames`."""
        changed = [i for i in range(len(self.steps)) if i == 0 or self.steps[i]["theta"] != self.steps[i - 1]["theta"]]
        if len(changed) > max_frames:
            changed = [changed[round(k)] for k in np.linspace(0, len(changed) - 1, max_frames)]
        return changed

    def frame(self, index: int) -> dict[str, Any]:
        """Step `index` as plain values for a figure: blocks (x, y, yaw rad, side) and the path as (N, 2) metres;
        a damaged scene message is named."""
        try:
            entities = {e["id"]: e for e in self.scenes[index]["entities"]}
            blocks = []
            for cube in entities["robot"]["cubes"]:
                q = cube["pose"]["orientation"]
                pos = cube["pose"]["position"]
                block = (float(pos["x"]), float(pos["y"]), 2 * math.atan2(q["z"], q["w"]), float(cube["size"]["x"]))
                if not (all(abs(v) <= MAX_COORD_M for v in block) and block[3] > 0):  # NaN fails too
                    raise ValueError(f"a block at {block}")
                blocks.append(block)
            if len(blocks) != BLOCKS:
                raise ValueError(f"{len(blocks)} blocks, not Smorphi's {BLOCKS}")
            pts = [[p["x"], p["y"]] for line in entities["coverage_path"]["lines"] for p in line["points"]]
            path = np.asarray(pts, dtype=float).reshape(-1, 2)
            if path.size and not np.all(np.abs(path) <= MAX_COORD_M):  # NaN fails too
                raise ValueError("a path point beyond any map's frame")
        except (KeyError, TypeError, ValueError, OverflowError, IndexError) as exc:
            raise self._damaged(f"scene message {index}", exc) from None
        return {"blocks": blocks, "path": path, "step": self.steps[index]}

    @property
    def episode_return(self) -> float:
        return float(sum(s["reward"] for s in self.steps if s.get("reward") is not None))


BLOCKS = 4
"""Smorphi's blocks: a scene draws each."""
MAX_COORD_M = 2 * MAX_ORIGIN_M
"""A scene's point lies within this of the map frame's zero (a map's origin and its extent); beyond, matplotlib
cannot draw it and the file is damaged."""

MAX_CHUNK_BYTES = 64 << 20
"""More than any chunk a recording holds (its chunks hold about 1 MiB; the map's grid of MAX_IMAGE_PIXELS cells,
in base64, 33 MB): a chunk that says it inflates beyond is refused before it is decompressed."""
MAX_RECORDING_BYTES = 512 << 20
"""The most a whole recording may inflate to: a few kilobytes of zstd can declare gigabytes."""


def _chunk_records(chunk: Any, budget: list[int], path: Path) -> Iterator[Any]:
    """The channels and messages of one chunk, decompressed within MAX_CHUNK_BYTES and what is left of `budget`;
    a record no chunk of ours holds ends the read in one line (a chunk of zeros would read as empty records)."""
    import zstandard
    from mcap.data_stream import ReadDataStream
    from mcap.opcode import Opcode
    from mcap.records import Channel, Message

    if chunk.compression not in ("zstd", ""):
        raise RecordingError(f"{path}: a chunk compressed with {chunk.compression[:20]!r}, which no recording is")
    declared = zstandard.frame_content_size(chunk.data) if chunk.compression == "zstd" else len(chunk.data)
    size = max(declared, chunk.uncompressed_size)
    if size > min(MAX_CHUNK_BYTES, budget[0]):
        raise RecordingError(f"{path}: a chunk that inflates to {size:,} bytes, beyond any recording's")
    budget[0] -= size
    data = chunk.data
    if chunk.compression == "zstd":
        data = zstandard.ZstdDecompressor().decompress(chunk.data, max_output_size=chunk.uncompressed_size)
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:  # 0: the writer computed none
        raise RecordingError(f"{path}: is damaged: a chunk's content does not match its checksum")
    stream = ReadDataStream(io.BytesIO(data))
    while stream.count < len(data):
        opcode, length = stream.read1(), stream.read8()
        if opcode == Opcode.CHANNEL:
            yield Channel.read(stream)
        elif opcode == Opcode.MESSAGE:
            yield Message.read(stream, length)
        elif opcode == Opcode.SCHEMA:
            stream.read(length)
        else:
            raise RecordingError(f"{path}: a chunk holds a record of opcode {opcode}, which no recording's does")


MIN_BYTES_PER_CONTAINER = 8
"""Our messages spend 30 bytes or more of JSON on each list or object (a scene's path point, 34; a step, 72):
`[[],[],...]` spends 3, and parsed takes 20 times its bytes, so 46 KB of zstd once took 7.6 GB."""
MAX_JSON_CONTAINERS = 16_000_000
"""Lists and objects the messages of one recording may hold: about what MAX_RECORDING_BYTES of ours hold (an
episode on map-1: 27,000 in 780 KB)."""


def _count_containers(data: bytes, what: str, path: Path, budget: list[int]) -> None:
    """Take the lists and objects of JSON `data` from `budget`, refusing, before it is parsed, JSON of more than one
    a MIN_BYTES_PER_CONTAINER bytes or beyond what is left."""
    containers = data.count(b"[") + data.count(b"{")  # counted before parsing: a bound, strings' brackets too
    budget[0] -= containers
    if budget[0] < 0 or containers * MIN_BYTES_PER_CONTAINER > len(data) + 64:
        raise RecordingError(f"{path}: {what} holds more lists and objects than smorphi-rl writes "
                             f"({containers:,} in {len(data):,} bytes)")  # fmt: skip


def _message(data: bytes, topic: str, path: Path, budget: list[int]) -> Any:
    """One message's JSON, within what is left of `budget` (lists and objects) and at most one a
    MIN_BYTES_PER_CONTAINER bytes; one that is not JSON (or nested past Python's limit) is named, not read as a
    cut."""
    _count_containers(data, f"a message on {topic}", path, budget)
    try:
        return json.loads(data)
    except (ValueError, RecursionError):
        raise RecordingError(f"{path}: a message on {topic} is not the JSON smorphi-rl writes") from None


def _ends_whole(fh: Any) -> bool:
    """Whether the open file ends in MCAP's closing magic, as a finished recording does (one cut short does not)."""
    try:
        if fh.seek(0, io.SEEK_END) < 2 * len(MCAP_MAGIC):  # the opening magic alone, or less
            return False
        fh.seek(-len(MCAP_MAGIC), io.SEEK_END)
        return bool(fh.read(len(MCAP_MAGIC)) == MCAP_MAGIC)
    except OSError:
        return False


def read_episode(path: str | Path) -> Episode:
    """Read a recording, complete or cut short (every complete chunk is recovered; `truncated` says so)."""
    from mcap.records import Channel, Chunk, Footer, Message, Metadata
    from mcap.stream_reader import StreamReader

    file = Path(path)
    if not file.name.endswith((SUFFIX, PART_SUFFIX)) and not file.is_dir():
        raise RecordingError(f"{path}: not a recording's name (smorphi-rl records NAME{SUFFIX}, NAME{PART_SUFFIX} "
                             "while it is written)")  # fmt: skip
    check_not_special(file, "recording", RecordingError)
    finished = file.with_name(file.name.removesuffix(PART_SUFFIX) + SUFFIX)
    if file.name.endswith(PART_SUFFIX) and not file.exists() and finished.exists():
        file = finished  # listed while written, finished since: the same recording, whole
    try:
        fh = file.open("rb")  # one handle for the whole read: a rename between two opens cannot part them
    except FileNotFoundError:
        raise RecordingError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise RecordingError(f"{path}: is a directory") from None
    except OSError as exc:  # no permission: one line, and a listing goes on to the next file
        raise RecordingError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    topics: dict[int, str] = {}
    meta: dict[str, str] = {}
    by_topic: dict[str, list[dict[str, Any]]] = {t: [] for t in OUR_TOPICS}
    complete = False
    budget, containers = [MAX_RECORDING_BYTES], [MAX_JSON_CONTAINERS]

    def records(fh: Any) -> Iterator[Any]:
        for record in StreamReader(fh, emit_chunks=True, record_size_limit=MAX_CHUNK_BYTES).records:
            yield from _chunk_records(record, budget, file) if isinstance(record, Chunk) else (record,)

    with fh:
        if fh.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise RecordingError(f"{path}: not an MCAP file")
        fh.seek(0)
        try:
            for record in records(fh):
                if isinstance(record, Channel):
                    topics[record.id] = record.topic
                elif isinstance(record, Message) and topics.get(record.channel_id) in by_topic:
                    by_topic[topics[record.channel_id]].append(
                        _message(record.data, topics[record.channel_id], file, containers)
                    )
                elif isinstance(record, Metadata) and record.name == METADATA_NAME:
                    meta = dict(record.metadata)  # its env_config is parsed as it is used: counted here
                    _count_containers(meta.get("env_config", "").encode(), "the metadata", file, containers)
                elif isinstance(record, Footer):
                    complete = True
        except RecordingError:
            raise
        except Exception as exc:  # a cut-short file ends in a partial record: keep what came before it
            # a finished file was damaged inside, not cut (a .part file is still being written, or was cut: one
            # finished since this read began ends whole, yet its read stopped at a record then half-written)
            if not file.name.endswith(PART_SUFFIX) and _ends_whole(fh):
                raise RecordingError(f"{path}: is damaged: it ends as a finished recording does, yet a record inside "
                                     f"it cannot be read ({type(exc).__name__})") from None  # fmt: skip
            complete = False
    if not topics or not any(t in OUR_TOPICS for t in topics.values()):
        cut = not complete and not topics
        what = "is damaged or cut short before any channel" if cut else "holds none of smorphi-rl's channels"
        raise RecordingError(f"{path}: {what} ({', '.join(OUR_TOPICS)})")
    steps = by_topic[TOPIC_STEP]
    if not steps:
        raise RecordingError(f"{path}: no step could be recovered" + ("" if complete else " (the file is cut short)"))
    largest, required = _largest_move(meta), STEP_SCHEMA["required"]
    for i, st in enumerate(steps):  # a step another writer made, or damaged: named, never a KeyError later
        missing = [k for k in required if k not in st] if isinstance(st, dict) else list(required)
        problem = _step_problem(st, largest) if not missing else None
        if not missing and not problem and st["step"]:  # every step after the reset state acted
            missing = [k for k in ACTED if k not in st]
        if missing:
            raise RecordingError(f"{path}: step message {i} lacks {', '.join(missing[:3])} (not a smorphi-rl step)")
        if problem:
            raise RecordingError(f"{path}: step message {i} is damaged ({problem})")
        if i and st["step"] <= steps[i - 1]["step"]:  # an episode's steps are numbered 0, 1, 2, ... as they ran
            raise RecordingError(f"{path}: step message {i} is damaged (step {st['step']} does not follow step "
                                 f"{steps[i - 1]['step']})")  # fmt: skip
    scenes = by_topic[TOPIC_SCENE][: len(steps)]
    steps = steps[: len(scenes)] if len(scenes) < len(steps) else steps
    if not steps:
        raise RecordingError(f"{path}: no scene message could be recovered (the robot's pose of each step)")
    grid = by_topic[TOPIC_MAP][0] if by_topic[TOPIC_MAP] else None
    return Episode(
        file,
        meta,
        steps,
        scenes,
        grid,
        [str(m.get("message", "")) for m in by_topic[TOPIC_LOG] if isinstance(m, dict)],
        not complete,
    )


def _largest_move(meta: dict[str, str]) -> int:
    """The largest move index the recorded env could take: 2 K for its K step sizes (a designer's 1, 4, 16: 6);
    MAX_MOVE where the metadata does not say (a file cut short before it)."""
    try:
        moves = json.loads(meta["env_config"]).get("moves", [1])
    except (KeyError, ValueError, AttributeError, RecursionError):
        return MAX_MOVE
    sizes = len(moves) if isinstance(moves, list) else 0
    return 2 * sizes if 1 <= sizes <= MAX_MOVE_SIZES else MAX_MOVE


def _step_problem(st: dict[str, Any], largest: int = MAX_MOVE) -> str | None:
    """What is wrong with a step message's values (types and ranges `replay` relies on), or None; an action's
    moves are indices 0..`largest`."""
    theta = st["theta"]
    if not (isinstance(theta, list) and len(theta) == 3 and all(is_finite_number(t) and 0 <= t <= 180 for t in theta)):
        return f"theta {str(theta)[:40]} is not three hinge angles in [0, 180]"
    for key in ("R1", "P_c", "coverage_free_pct"):
        if not is_finite_number(st[key]):
            return f"{key} {str(st[key])[:20]} is not a finite number"
    if not 0 <= st["P_c"] <= 100 or not 0 <= st["coverage_free_pct"] <= 100:
        return "a coverage outside [0, 100] %"
    for key in ("reward", "R2"):  # step 0 has none (a recording of before 2026-12-07 holds nulls there)
        if st.get(key) is not None and not is_finite_number(st[key]):
            return f"{key} {str(st[key])[:20]} is not a finite number"
    if type(st["P_len"]) is not int or st["P_len"] < 0 or type(st["step"]) is not int or st["step"] < 0:
        return "P_len or step is not a whole number >= 0"
    if st["P_len"] > MAX_P_LEN:
        return f"P_len {str(st['P_len'])[:24]} beyond any coverage path's {MAX_P_LEN:,} tile moves"
    if st["step"] > MAX_EPISODE_STEPS:
        return f"step {str(st['step'])[:24]} beyond any episode's {MAX_EPISODE_STEPS:,}"
    action = st.get("action")
    if action is not None and not (isinstance(action, list) and len(action) == 3
                                   and all(type(a) is int and 0 <= a <= largest for a in action)):  # fmt: skip
        return f"action {str(action)[:20]} is not three moves in 0..{largest}"
    if not isinstance(st["map"], str) or not isinstance(st["feasible"], bool):
        return "map is not a name or feasible is not true or false"
    return None


def episode_files(directory: str | Path) -> list[Path]:
    """Every recording under `directory` (finished and .part), in name order."""
    root = Path(directory)
    return sorted(p for p in root.rglob("*") if p.is_file() and p.name.endswith((SUFFIX, PART_SUFFIX)))
