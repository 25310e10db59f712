"""Writing recordings: one episode's crash-safe MCAP file, and the env wrapper that records every Nth episode."""

from __future__ import annotations

import json
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym

from smorphi_rl.coverage import CoverageResult
from smorphi_rl.env import MorphologyEnv
from smorphi_rl.geometry import angles_text
from smorphi_rl.recording.messages import (
    JSON_SEPARATORS,
    LOG_CUT,
    LOG_ENDED,
    METADATA_NAME,
    PART_SUFFIX,
    PATH_CACHE_SIZE,
    PATH_PLACEHOLDER,
    STEP_PERIOD_NS,
    STEP_SCHEMA,
    SUFFIX,
    TOPIC_LOG,
    TOPIC_MAP,
    TOPIC_SCENE,
    TOPIC_STEP,
    RecordingError,
    foxglove_schema,
    grid_message,
    log_message,
    path_line,
    scene_message,
    step_record,
)
from smorphi_rl.rundir import naming


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


class EpisodeWriter:
    """One episode's MCAP file, crash-safe: NAME.mcap.part until `finish` renames it to NAME.mcap."""

    def __init__(self, path: Path, metadata: dict[str, str], flush_steps: int) -> None:
        self.final = path
        self.part = path.with_name(path.name.removesuffix(SUFFIX) + PART_SUFFIX)
        self.part.parent.mkdir(parents=True, exist_ok=True)
        self._fh = self.part.open("wb")
        self.broken = False
        """Set when a write failed (a full disk): the file is left as its last flushed chunk, and every later call
        does nothing, so closing the env after the failure does not fail again."""
        self.flush_steps = flush_steps
        self.steps = 0
        self._channels: dict[str, int] = {}
        try:
            self._start(metadata)
        except Exception:  # no writer comes of it: its file closed and, when empty, removed
            self.broken = True
            self._abandon()
            raise

    def _start(self, metadata: dict[str, str]) -> None:
        from mcap.writer import CompressionType, Writer

        with self._writing():
            self._writer = Writer(self._fh, compression=CompressionType.ZSTD)
            self._writer.start(profile="", library="smorphi-rl")
            for topic, name, schema in ((TOPIC_STEP, "smorphi_rl.Step", json.dumps(STEP_SCHEMA).encode()),
                                        (TOPIC_MAP, "foxglove.Grid", foxglove_schema("Grid")),
                                        (TOPIC_SCENE, "foxglove.SceneUpdate", foxglove_schema("SceneUpdate")),
                                        (TOPIC_LOG, "foxglove.Log", foxglove_schema("Log"))):  # fmt: skip
                schema_id = self._writer.register_schema(name=name, encoding="jsonschema", data=schema)
                self._channels[topic] = self._writer.register_channel(topic, message_encoding="json",
                                                                      schema_id=schema_id)  # fmt: skip
            self._writer.add_metadata(METADATA_NAME, {k: str(v) for k, v in metadata.items()})

    @contextmanager
    def _writing(self) -> Iterator[None]:
        """Run a write; an OSError (a full disk) names the file, as every other write's does, and leaves the file at
        its last flushed chunk (which replays), or removes it when nothing reached the disk."""
        try:
            yield
        except OSError as exc:
            self.broken = True
            self._abandon()
            raise naming(exc, self.part) from None

    def _abandon(self) -> None:
        """Close the file as it stands (its last flushed chunk replays); remove it when nothing reached the disk."""
        with suppress(OSError):
            self._fh.close()
        with suppress(OSError):
            if self.part.stat().st_size == 0:
                self.part.unlink()

    def write(self, topic: str, message: dict[str, Any] | bytes, ns: int) -> None:
        """One message, a dict (JSON-encoded here) or JSON already encoded."""
        if self.broken:
            return
        data = message if isinstance(message, bytes) else json.dumps(message, separators=JSON_SEPARATORS).encode()
        ns = int(ns)  # a float or negative log_time corrupts the whole file (the notes)
        with self._writing():
            self._writer.add_message(self._channels[topic], log_time=ns, publish_time=ns, data=data)

    def end_step(self) -> None:
        """Count a step; flush the chunk every `flush_steps` steps."""
        self.steps += 1
        if self.steps % self.flush_steps == 0:
            self.flush()

    def flush(self) -> None:
        if self.broken:
            return
        with self._writing():
            self._writer.flush()
            self._fh.flush()

    def finish(self) -> Path | None:
        """Write the summary, close and rename to NAME.mcap; None after a failed write (which kept NAME.mcap.part as
        far as it was flushed, or removed it empty)."""
        if self.broken:
            return None
        with self._writing():
            self._writer.finish()
            self._fh.close()
            self.part.replace(self.final)
        return self.final


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
        self._end(f"{LOG_CUT} by a reset")
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
                best = f"{angles_text(info['best_theta'])} R1 {info['best_R1']:.2f}"
                self._end(f"{LOG_ENDED} {self._step} steps ({'terminated' if terminated else 'truncated'}); "
                          f"best {best}")  # fmt: skip
        return obs, reward, terminated, truncated, info

    def close(self) -> None:
        """End the episode being recorded as cut; a write that fails here (a full disk) leaves its file as far as it
        was flushed and does not fail the close: the run already stopped, or stops, on the write that failed first."""
        try:
            self._end(f"{LOG_CUT}: the env was closed")
        except OSError:
            self._writer = None
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
        theta = angles_text(info["theta"])
        self._writer.write(TOPIC_LOG, log_message(f"episode {episode} start on {env.grid_map.name} at {theta}",
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
