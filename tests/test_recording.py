"""MCAP recordings: round trip, Foxglove schemas, crash recovery, every-Nth, replay command, bad input."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from smorphi_rl.cli import main
from smorphi_rl.env import MorphologyEnv
from smorphi_rl.recording import (
    OUR_TOPICS,
    PART_SUFFIX,
    RecordingConfig,
    RecordingError,
    RecordingWrapper,
    episode_files,
    read_episode,
    step_record,
)
from smorphi_rl.recording.messages import foxglove_schema
from smorphi_rl.training.config import make_env

ROOT = Path(__file__).resolve().parents[1]
MAP_1 = str(ROOT / "maps" / "map-1.yaml")
META = {"run": "unit", "algorithm": "ppo", "seed": "7", "config": "{}"}


def recorded_env(tmp_path: Path, every: int = 1, flush_steps: int = 50, max_steps: int = 40,
                 map_path: str = MAP_1) -> RecordingWrapper:  # fmt: skip
    rec = RecordingConfig(str(tmp_path / "episodes"), every=every, flush_steps=flush_steps, metadata=META)
    env = make_env({"maps": [map_path], "max_steps": max_steps, "recording": rec.to_dict()})
    assert isinstance(env, RecordingWrapper)
    return env


def play(env, seed: int, rng: np.random.Generator, steps: int | None = None) -> list[dict]:
    """Run one episode (or `steps` steps of it) with random actions; return what the env produced, as records."""
    _, info = env.reset(seed=seed)
    produced = [step_record(0, info)]
    done, n = False, 0
    while not done and (steps is None or n < steps):
        action = rng.integers(0, 3, size=3)
        _, reward, terminated, truncated, info = env.step(action)
        n += 1
        produced.append(step_record(n, info, action, reward))
        done = terminated or truncated
    return produced


def test_round_trip_gives_exactly_the_steps_the_env_produced(tmp_path):
    env = recorded_env(tmp_path)
    produced = play(env, 3, np.random.default_rng(0))
    (path,) = episode_files(tmp_path / "episodes")
    assert path.name.endswith(".mcap") and not path.name.endswith(PART_SUFFIX)  # finished and renamed
    ep = read_episode(path)
    assert not ep.truncated
    assert ep.steps == json.loads(json.dumps(produced))  # every field, every step, in order
    assert len(ep.scenes) == len(produced) and ep.grid is not None
    assert ep.metadata["run"] == "unit" and ep.metadata["algorithm"] == "ppo" and ep.metadata["seed"] == "7"
    assert ep.metadata["map"] == "map-1" and ep.metadata["reset_seed"] == "3" and ep.metadata["worker"] == "0"
    assert ep.logs[0].startswith("episode 0 start on map-1") and "episode end after 40 steps" in ep.logs[-1]
    assert (ep.grid_cells() == MorphologyEnv({"maps": [MAP_1]}).grid_map.cells).all()  # the map round-trips
    assert ep.best is not None and ep.best["R1"] == max(p["R1"] for p in produced)


def test_every_message_validates_against_its_schema(tmp_path):
    env = recorded_env(tmp_path)
    play(env, 1, np.random.default_rng(1))
    (path,) = episode_files(tmp_path / "episodes")
    with path.open("rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None
        names = {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}
        assert names == {"/smorphi/step": "smorphi_rl.Step", "/map": "foxglove.Grid",
                         "/morphology": "foxglove.SceneUpdate", "/log": "foxglove.Log"}  # fmt: skip
        counts: dict[str, int] = {}
        for schema, channel, message in reader.iter_messages():
            assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
            jsonschema.validate(json.loads(message.data), json.loads(schema.data))
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    assert counts == {"/map": 1, "/log": 2, "/smorphi/step": 41, "/morphology": 41}
    for name in ("Grid", "SceneUpdate", "Log"):  # the shipped schemas are Foxglove's, and valid JSON Schemas
        schema = json.loads((ROOT / "smorphi_rl" / "schemas" / f"{name}.json").read_text())
        assert schema["title"] == f"foxglove.{name}"
        jsonschema.Draft202012Validator.check_schema(schema)


def foxglove_refuses(schema: dict, path: str = "") -> list[str]:
    """The fields Foxglove's JSON-schema reader (parseJsonSchema) cannot type: its `type` must be one of six names,
    never a union (["number", "null"]) or absent (a `$ref` to another file, which a recording does not carry)."""
    refused = []
    for name, field in schema.get("properties", {}).items():
        where = f"{path}.{name}".lstrip(".")
        if isinstance(field.get("oneOf"), list) and all("const" in a for a in field["oneOf"]):
            continue  # an enum
        kind = field.get("type")
        if kind == "object":
            refused += foxglove_refuses(field, where)
        elif kind == "array":
            item = field.get("items", {})
            if item.get("type") == "object":
                refused += foxglove_refuses(item, where)
            elif item.get("type") not in ("boolean", "integer", "number", "string"):
                refused.append(f"{where}[]: {item.get('type')!r}")
        elif kind not in ("boolean", "integer", "number", "string"):
            refused.append(f"{where}: {kind!r}")
    return refused


def test_foxglove_can_type_every_field_of_every_channel():
    """The step's action, reward and R2 were typed ["number", "null"], and the Grid's and SceneUpdate's lineage a
    `$ref` to a file no recording holds: Foxglove's reader refused the channel whole."""
    from smorphi_rl.recording.messages import STEP_SCHEMA

    schemas = {name: json.loads(foxglove_schema(name)) for name in ("Grid", "SceneUpdate", "Log")}
    for name, schema in {**schemas, "Step": STEP_SCHEMA}.items():
        assert schema["type"] == "object" and foxglove_refuses(schema) == [], name


def test_a_scene_holds_four_blocks_and_the_coverage_path(tmp_path):
    env = recorded_env(tmp_path)
    play(env, 2, np.random.default_rng(2))
    ep = read_episode(episode_files(tmp_path / "episodes")[0])
    base = env.unwrapped
    planned = 0
    for i in (0, 10, 40):
        frame = ep.frame(i)
        assert len(frame["blocks"]) == 4
        plan = base.plan(tuple(ep.steps[i]["theta"]))
        if plan.feasible:
            assert len(frame["path"]) == len(plan.path_tiles) > 0
            planned += 1
    assert planned  # the path check ran


def test_only_every_nth_episode_is_recorded_with_unique_names(tmp_path):
    rng = np.random.default_rng(0)
    env_a, env_b = recorded_env(tmp_path, every=3, max_steps=5), recorded_env(tmp_path, every=3, max_steps=5)
    for i in range(7):
        play(env_a, i, rng)
        play(env_b, i, rng)
    env_a.close()
    env_b.close()
    files = episode_files(tmp_path / "episodes")
    assert len(files) == 2 * 3  # episodes 0, 3 and 6 of each env
    assert len({f.name for f in files}) == 6 and {env_a.instance, env_b.instance} == {
        f.name.split("-")[2] for f in files
    }
    assert sorted(int(read_episode(f).metadata["episode"]) for f in files) == [0, 0, 3, 3, 6, 6]


def test_a_file_cut_short_is_recovered_up_to_its_last_flush(tmp_path, capsys):
    env = recorded_env(tmp_path, flush_steps=10, max_steps=200)
    produced = play(env, 5, np.random.default_rng(5), steps=35)  # flushed at steps 10, 20, 30; then "killed"
    (part,) = episode_files(tmp_path / "episodes")
    assert part.name.endswith(PART_SUFFIX)
    copy = tmp_path / "killed.mcap.part"
    shutil.copyfile(part, copy)  # what a killed worker leaves behind
    ep = read_episode(copy)
    assert ep.truncated and 30 <= len(ep.steps) <= 36  # the chunks flushed every 10 recorded steps
    assert ep.steps == json.loads(json.dumps(produced[: len(ep.steps)]))
    assert main(["replay", str(copy)]) == 0
    out = capsys.readouterr().out
    assert "recovered" in out and "cut short" in out

    env.close()  # finishing the real one turns it into a complete file
    (done,) = episode_files(tmp_path / "episodes")
    data = done.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])  # a finished file truncated mid-way
    with pytest.raises(RecordingError):
        read_episode(tmp_path / "nothing-here.mcap")
    partial = read_episode(cut)
    assert partial.truncated and 1 <= len(partial.steps) <= len(produced)
    assert partial.steps == json.loads(json.dumps(produced[: len(partial.steps)]))


def test_a_finished_recording_damaged_inside_is_refused_not_read_as_cut_short(tmp_path, capsys):
    """Two bytes changed inside a chunk of a whole file were reported as "0 steps from a file cut short", exit 0."""
    env = recorded_env(tmp_path, flush_steps=10, max_steps=40)
    play(env, 5, np.random.default_rng(5))
    env.close()
    (done,) = episode_files(tmp_path / "episodes")
    data = bytearray(done.read_bytes())
    at = data.index(b"\x28\xb5\x2f\xfd", data.index(b"\x28\xb5\x2f\xfd") + 4) + 200  # inside the second chunk
    data[at : at + 2] = bytes(255 - b for b in data[at : at + 2])
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    assert main(["replay", str(damaged)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{damaged}: is damaged" in err, err
    data[at : at + 2] = bytes(255 - b for b in data[at : at + 2])  # mended, then cut short after that chunk
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(bytes(data[: at + 1000]))
    assert read_episode(cut).truncated  # a file cut short is read up to its cut
    crc = data.index(b"\x28\xb5\x2f\xfd") - 8 - 8 - 4  # the first chunk's CRC, before "zstd" (4 + 4) and a length (8)
    data[crc : crc + 4] = bytes(255 - b for b in data[crc : crc + 4])  # a checksum that no longer matches
    damaged.write_bytes(bytes(data))
    assert main(["replay", str(damaged)]) == 1
    assert "does not match its checksum" in capsys.readouterr().err


def test_a_recording_whose_disk_fills_mid_episode_keeps_what_it_flushed(tmp_path, monkeypatch):
    """A full disk at a chunk's flush: the error names the file, the file keeps its flushed chunks (and replays),
    and the steps and the close after it write nothing and raise nothing (closing once failed again)."""
    env = recorded_env(tmp_path, flush_steps=10, max_steps=200)
    produced = play(env, 5, np.random.default_rng(5), steps=25)  # flushed at steps 10 and 20
    writer = env._writer
    assert writer is not None

    def full(*_: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(writer._writer, "flush", full)
    with pytest.raises(OSError) as exc:
        for _ in range(10):  # the episode goes on; its next flush fails
            env.step(np.array([1, 1, 1]))
    assert exc.value.filename == str(writer.part) and writer.broken
    env.step(np.array([1, 1, 1]))
    env.close()
    assert writer.finish() is None and not writer.final.exists()
    ep = read_episode(writer.part)
    assert ep.truncated and 20 <= len(ep.steps) <= 26
    assert ep.steps == json.loads(json.dumps(produced[: len(ep.steps)]))


def test_a_disk_that_fills_as_the_env_closes_fails_no_close(tmp_path, monkeypatch):
    """The disk fills elsewhere (a trial's checkpoint) and RLlib stops its runners: the recording's last write
    failed in `close`, the runner's stop failed and Ray took 60 s to end it, with two lines on the terminal."""
    env = recorded_env(tmp_path, flush_steps=10, max_steps=200)
    play(env, 5, np.random.default_rng(5), steps=25)
    writer = env._writer
    assert writer is not None and not writer.broken

    def full(*_: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(writer._writer, "finish", full)
    env.close()
    assert writer.broken and not writer.final.exists()
    assert read_episode(writer.part).truncated  # kept as far as it was flushed


def test_replay_command_summary_steps_png_gif_and_listing(tmp_path, capsys):
    env = recorded_env(tmp_path, max_steps=30)
    for seed in range(2):
        play(env, seed, np.random.default_rng(seed))
    first, second = episode_files(tmp_path / "episodes")
    png, gif = tmp_path / "r.png", tmp_path / "r.gif"
    assert main(["replay", str(first), "--steps", "--png", str(png), "--gif", str(gif)]) == 0
    out, err = capsys.readouterr()
    assert re.search(r"gif: frames drawn \[#{30}\] (\d+)/\1 ", err), err  # a GIF takes a while: its bar, whole
    assert "map        map-1" in out and "run        unit (PPO, seed 7)" in out and "best       step" in out
    assert sum(1 for line in out.splitlines() if line[:5].strip().isdigit()) == 31  # the step table
    assert png.stat().st_size > 10_000 and gif.read_bytes()[:6] in (b"GIF89a", b"GIF87a")
    assert main(["replay", str(first), "--png", str(png)]) == 1  # drawn already: replaced only with --force
    assert "exists; pass --force" in capsys.readouterr().err
    assert main(["replay", str(first), "--png", str(png), "--gif", str(gif), "--force"]) == 0
    assert main(["replay", str(tmp_path / "episodes")]) == 0
    listing = capsys.readouterr().out
    assert first.name in listing and second.name in listing and "2 recordings" in listing
    (tmp_path / "episodes" / "sub").mkdir()  # one in a subfolder is named with it; one unreadable is counted apart
    shutil.copyfile(second, tmp_path / "episodes" / "sub" / second.name)
    (tmp_path / "episodes" / "junk.mcap").write_bytes(b"not an mcap")
    assert main(["replay", str(tmp_path / "episodes")]) == 0
    listing = capsys.readouterr().out.splitlines()
    assert any(line.startswith(f"sub/{second.name} ") for line in listing)
    assert listing[-1] == f"4 recordings in {tmp_path / 'episodes'} (1 unreadable)"


def test_replay_draws_the_area_each_step_covers_planned_again_with_the_recordings_planner(tmp_path):
    """`replay --png` drew the path alone: the recording holds no cells, so the area is planned again, and only
    where the plan gives the recorded P_c and P_len."""
    from dataclasses import replace

    from smorphi_rl.geometry import Morphology
    from smorphi_rl.maps import load_map
    from smorphi_rl.planning import PAPER_PLANNING

    env = recorded_env(tmp_path, max_steps=12)
    play(env, 3, np.random.default_rng(3))
    env.close()
    (recording,) = episode_files(tmp_path / "episodes")
    ep = read_episode(recording)
    grid, picks = ep.grid_map(), [0, len(ep.steps) - 1]
    evaluator = PAPER_PLANNING.evaluator(load_map(MAP_1))
    for index, mask in zip(picks, ep.covered(picks, grid), strict=True):
        expected = evaluator.plan(Morphology(*ep.steps[index]["theta"])).covered
        assert mask is not None and expected is not None and mask.any() and np.array_equal(mask, expected)
    other = json.loads(ep.metadata["env_config"]) | {"planner": "fit"}  # another planner's figures: none drawn
    assert replace(ep, metadata=ep.metadata | {"env_config": json.dumps(other)}).covered(picks, grid) == [None, None]
    assert replace(ep, metadata={}).covered(picks, grid) == [None, None]
    older = json.loads(ep.metadata["env_config"]) | {"a_key_of_another_version": 1, "max_steps": 10**9}
    again = replace(ep, metadata=ep.metadata | {"env_config": json.dumps(older)}).covered(picks, grid)
    assert all(mask is not None for mask in again)  # only the planner's keys are read
    png = tmp_path / "r.png"
    assert main(["replay", str(recording), "--png", str(png)]) == 0


def test_replays_listing_is_as_wide_as_what_its_columns_hold(tmp_path, capsys, monkeypatch):
    """A map named `turtlebot3_world` ran into the algorithm's column (the map column was 8 wide)."""
    from smorphi_rl.maps import load_map, save_map

    floor = save_map(load_map(MAP_1), tmp_path / "turtlebot3_world.yaml")
    env = recorded_env(tmp_path, max_steps=10, map_path=str(floor))
    play(env, 0, np.random.default_rng(0))
    env.close()
    assert main(["replay", str(tmp_path / "episodes")]) == 0
    head, row = capsys.readouterr().out.splitlines()[:2]
    algo = row[head.index(" algo ") + 1 :]
    assert row[head.index(" map ") + 1 :].startswith("turtlebot3_world ") and algo.startswith("ppo ")
    from smorphi_rl.cli import policy

    monkeypatch.setattr(policy, "LISTING_PROGRESS_FROM", 0)  # a folder of hundreds: the reading shows its progress
    assert main(["replay", str(tmp_path / "episodes")]) == 0
    assert "recordings read" in capsys.readouterr().err


def test_replays_listing_lines_up_a_map_named_in_wide_characters(tmp_path, capsys):
    """A CJK character takes two terminal columns: counted as one, the columns after a map named 会議室 slipped."""
    from smorphi_rl.cli.common import columns
    from smorphi_rl.maps import load_map, save_map

    for name in ("会議室", "hall"):
        floor = save_map(load_map(MAP_1), tmp_path / f"{name}.yaml")
        env = recorded_env(tmp_path, max_steps=10, map_path=str(floor))
        play(env, 0, np.random.default_rng(0))
        env.close()
    assert main(["replay", str(tmp_path / "episodes")]) == 0
    head, *rows = capsys.readouterr().out.splitlines()[:3]
    at = columns(head[: head.index(" algo ") + 1])
    assert columns("会議室") == 6 and sorted(columns(row[: row.index(" ppo ") + 1]) for row in rows) == [at, at]


def test_an_episode_of_several_step_sizes_replays(tmp_path, capsys):
    """A designer's env (moves 1, 4, 16) records actions 0..6 per hinge; replay read only 0..2 as moves."""
    rec = RecordingConfig(str(tmp_path / "episodes"), every=1, metadata=META)
    env = make_env({"maps": [MAP_1], "max_steps": 20, "moves": [1, 4, 16], "recording": rec.to_dict()})
    env.reset(seed=0)
    for _ in range(20):
        env.step(np.array([6, 0, 5]))
    env.close()
    (path,) = episode_files(tmp_path / "episodes")
    assert read_episode(path).steps[1]["action"] == [6, 0, 5]
    with path.open("rb") as fh:  # and each step holds to the schema the file carries
        for schema, _channel, message in make_reader(fh).iter_messages(topics=["/smorphi/step"]):
            jsonschema.validate(json.loads(message.data), json.loads(schema.data))
    assert main(["replay", str(path)]) == 0, capsys.readouterr().err
    beyond = _tampered(path, tmp_path / "beyond.mcap", "/smorphi/step", lambda m: m | {"action": [7, 0, 0]})
    assert main(["replay", str(beyond)]) == 1
    assert "action [7, 0, 0] is not three moves in 0..6" in capsys.readouterr().err


def _foreign_mcap(path: Path) -> None:
    with path.open("wb") as fh:
        writer = Writer(fh)
        writer.start()
        schema = writer.register_schema(name="x", encoding="jsonschema", data=b"{}")
        channel = writer.register_channel("/other", message_encoding="json", schema_id=schema)
        writer.add_message(channel, log_time=0, publish_time=0, data=b"{}")
        writer.finish()


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"not an mcap file at all", "not an MCAP file"),
        (b"\x89MCAP0\r\n\x01\x02", "cut short before any channel"),
        (None, "holds none of smorphi-rl's channels"),
    ],
)
def test_bad_recordings_give_one_line_and_exit_1(tmp_path, capsys, content, message):
    path = tmp_path / "bad.mcap"
    if content is None:
        _foreign_mcap(path)
    else:
        path.write_bytes(content)
    assert main(["replay", str(path)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err and "Traceback" not in err


def _one_chunk_mcap(path: Path, data: bytes, declared: int) -> None:
    """An MCAP file of a header and one zstd chunk that says it inflates to `declared` bytes."""
    import struct

    import zstandard
    from mcap.opcode import Opcode

    def record(opcode: int, body: bytes) -> bytes:
        return struct.pack("<BQ", opcode, len(body)) + body

    def text(value: str) -> bytes:
        return struct.pack("<I", len(value)) + value.encode()

    packed = zstandard.compress(data)
    chunk = struct.pack("<QQQI", 0, 0, declared, 0) + text("zstd") + struct.pack("<Q", len(packed)) + packed
    path.write_bytes(b"\x89MCAP0\r\n" + record(Opcode.HEADER, text("") + text("")) + record(Opcode.CHUNK, chunk))


@pytest.mark.parametrize(
    ("size", "declared", "message"),
    [
        (1 << 20, 3 << 30, "inflates to 3,221,225,472 bytes"),  # the frame holds 1 MiB, the chunk says 3 GiB
        (65 << 20, 1 << 20, "inflates to 68,157,440 bytes"),  # the frame itself says 65 MiB: 20 KB on disk
        (1 << 20, 1 << 20, "a record of opcode 0"),  # zeros read as a million empty records
    ],
)
def test_a_chunk_that_inflates_beyond_any_recording_is_refused_before_it_is_read(tmp_path, capsys, size, declared,
                                                                                 message):  # fmt: skip
    """A few kilobytes of zstd can inflate to gigabytes: a 64 KB file once took 2.2 GB and over a minute."""
    path = tmp_path / "bomb.mcap"
    _one_chunk_mcap(path, bytes(size), declared)
    assert path.stat().st_size < 100_000
    assert main(["replay", str(path)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err


def test_messages_that_parse_into_millions_of_lists_are_refused_before_they_are_parsed(tmp_path, capsys):
    """46 KB of zstd holding `[[],[],...]` messages on /log took 7.6 GB as Python lists (20 times their bytes)."""
    from mcap.writer import CompressionType, Writer

    path = tmp_path / "lists.mcap"
    with path.open("wb") as fh:
        writer = Writer(fh, compression=CompressionType.ZSTD)
        writer.start()
        schema = writer.register_schema("log", "jsonschema", b"{}")
        channel = writer.register_channel("/log", "json", schema)
        writer.add_message(channel, log_time=0, publish_time=0, data=b"[" + b"[]," * 6_000_000 + b"[]]")
        writer.finish()
    assert path.stat().st_size < 100_000
    assert main(["replay", str(path)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "a message on /log holds more lists and objects than smorphi-rl" in err, err


def test_metadata_that_parses_into_millions_of_lists_is_refused_before_it_is_parsed(tmp_path, capsys):
    """The metadata's env_config was parsed without the messages' count: 15 MB of `[[],[],...]` took 364 MB."""
    from mcap.writer import CompressionType, Writer

    path = tmp_path / "meta.mcap"
    with path.open("wb") as fh:
        writer = Writer(fh, compression=CompressionType.ZSTD)
        writer.start()
        writer.add_metadata("smorphi_rl", {"env_config": "[" + "[]," * 1_000_000 + "[]]"})
        writer.finish()
    assert main(["replay", str(path)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "the metadata holds more lists and objects than smorphi-rl" in err, err


def test_replay_of_a_folder_without_recordings_and_of_a_missing_file(tmp_path, capsys):
    assert main(["replay", str(tmp_path)]) == 1
    assert "holds no MCAP recordings" in capsys.readouterr().err
    assert main(["replay", str(tmp_path / "absent.mcap")]) == 1
    assert "no such file" in capsys.readouterr().err


def test_a_listing_goes_on_past_a_file_it_may_not_read_and_finds_one_finished_since(tmp_path, capsys, monkeypatch):
    """A file without read permission ended the whole listing in a PermissionError line; a .part renamed to .mcap
    once listed was "unreadable: no such file", and a rename between the reader's two opens a traceback."""
    env = recorded_env(tmp_path, every=1)
    for seed in (1, 2):
        play(env, seed, np.random.default_rng(seed), steps=3)
    env.reset(seed=3)  # the third episode's file is a .part until it ends
    first, second = (p for p in episode_files(tmp_path / "episodes") if p.name.endswith(".mcap"))
    opened = Path.open

    def refusing(self, *args, **kwargs):
        if self == second:
            raise PermissionError(13, "Permission denied", str(self))
        return opened(self, *args, **kwargs)

    monkeypatch.setattr(Path, "open", refusing)
    assert main(["replay", str(tmp_path / "episodes")]) == 0
    out = capsys.readouterr().out
    assert "unreadable: cannot be read (Permission denied)" in out and out.count(first.name) == 1
    monkeypatch.undo()
    (part,) = (p for p in episode_files(tmp_path / "episodes") if p.name.endswith(PART_SUFFIX))
    env.close()  # finished: renamed to .mcap after the listing named it .part
    assert not part.exists() and len(read_episode(part).steps) == 1


def test_recording_config_is_validated():
    with pytest.raises(RecordingError, match="'every' must be a positive integer"):
        RecordingConfig("/tmp/x", every=0)
    with pytest.raises(RecordingError, match="must be absolute"):
        RecordingConfig("relative/dir", every=1)
    assert set(OUR_TOPICS) == {"/smorphi/step", "/map", "/morphology", "/log"}


@pytest.mark.slow
def test_two_env_runners_with_several_envs_each_write_distinct_valid_files(tmp_path):
    from smorphi_rl import cluster
    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.training.config import (
        TrainConfig,
        algorithm_config,
        recording_settings,
        register_env,
        standalone_algorithm,
    )

    cfg = TrainConfig(env=EnvConfig.from_dict({"maps": [MAP_1], "max_steps": 20}), record_every=2,
                      num_env_runners=2, envs_per_runner=3)  # fmt: skip
    with cluster.ray_session(None):
        register_env()
        config = algorithm_config(cfg, recording=recording_settings(cfg, tmp_path, "vector"))
        with standalone_algorithm(config) as algo:  # stopping closes every env: episodes in progress finish
            algo.train()
    files = episode_files(tmp_path / "episodes")
    assert files and not [f for f in files if f.name.endswith(PART_SUFFIX)]
    instances = {(f.name.split("-")[1], f.name.split("-")[2]) for f in files}
    assert {w for w, _ in instances} == {"w01", "w02"} and len(instances) == 2 * 3  # 2 runners x 3 sub-envs
    for f in files:
        ep = read_episode(f)
        assert not ep.truncated and ep.metadata["run"] == "vector" and ep.metadata["algorithm"] == "ppo"
        assert int(ep.metadata["episode"]) % 2 == 0
        assert [s["step"] for s in ep.steps] == list(range(len(ep.steps)))


def test_a_recording_whose_steps_lack_fields_is_one_line(tmp_path, capsys):
    """A step message without R1 (another writer's, or damaged) is named, not a KeyError."""
    from mcap.writer import Writer

    from smorphi_rl.cli import main

    path = tmp_path / "x.mcap"
    with path.open("wb") as fh:
        writer = Writer(fh)
        writer.start()
        schema = writer.register_schema("smorphi_rl.Step", "jsonschema", b"{}")
        channel = writer.register_channel("/smorphi/step", "json", schema)
        writer.add_message(channel, 0, json.dumps({"step": 0, "theta": [1, 2, 3]}).encode(), 0)
        writer.finish()
    code = main(["replay", str(path)])
    err = capsys.readouterr().err
    assert code == 1 and "step message 0 lacks" in err and err.count("\n") == 1


def test_a_recording_whose_reset_state_holds_nulls_and_one_whose_step_lacks_its_action(tmp_path, capsys):
    """Recordings before 2026-12-07 wrote step 0's action, reward and R2 as null: they still replay. A later step
    without its action is named."""
    env = recorded_env(tmp_path, max_steps=5)
    play(env, 0, np.random.default_rng(0))
    (source,) = episode_files(tmp_path / "episodes")
    nulls = _tampered(source, tmp_path / "old.mcap", "/smorphi/step",
                      lambda m: m if m["step"] else m | {"action": None, "reward": None, "R2": None})  # fmt: skip
    assert main(["replay", str(nulls), "--steps"]) == 0
    assert re.search(r"^ +0 .* - +- ", capsys.readouterr().out, re.M)  # step 0: no action, no reward
    lacking = _tampered(source, tmp_path / "bad.mcap", "/smorphi/step",
                        lambda m: {k: v for k, v in m.items() if k != "action"})  # fmt: skip
    assert main(["replay", str(lacking)]) == 1
    assert "step message 1 lacks action" in capsys.readouterr().err


def _tampered(source: Path, target: Path, topic: str, edit) -> Path:
    """A copy of a real recording with every message on `topic` changed by `edit` (a dict in, a dict or the
    message's bytes out)."""
    with source.open("rb") as fh, target.open("wb") as out:
        reader, writer = make_reader(fh), Writer(out)
        writer.start()
        channels: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages():
            if channel.id not in channels:
                sid = writer.register_schema(schema.name, schema.encoding, schema.data) if schema else 0
                channels[channel.id] = writer.register_channel(channel.topic, channel.message_encoding, sid)
            data = message.data
            if channel.topic == topic:
                edited = edit(json.loads(data))
                data = edited if isinstance(edited, bytes) else json.dumps(edited).encode()
            writer.add_message(channels[channel.id], message.log_time, data, message.publish_time)
        with source.open("rb") as again:  # the run's and the env's metadata, as recorded
            for record in make_reader(again).iter_metadata():
                writer.add_metadata(record.name, record.metadata)
        writer.finish()
    return target


def _robot(scene: dict, edit) -> dict:
    """A scene message with its robot's cubes changed by `edit`."""
    for entity in scene["entities"]:
        if entity["id"] == "robot":
            entity["cubes"] = edit(entity["cubes"])
    return scene


def _at(cube: dict, x: object) -> dict:
    return cube | {"pose": cube["pose"] | {"position": cube["pose"]["position"] | {"x": x}}}


@pytest.mark.parametrize(("topic", "edit", "message"), [
    ("/smorphi/step", lambda m: m | {"theta": "abc"}, "step message 0 is damaged (theta abc is not three hinge"),
    ("/smorphi/step", lambda m: m | {"theta": [1e30, 5, 5]}, "is not three hinge angles in [0, 180]"),
    ("/smorphi/step", lambda m: m | {"R1": float("nan")}, "R1 nan is not a finite number"),
    ("/map", lambda m: m | {"data": "!!!notbase64"}, "the map message is damaged"),
    ("/map", lambda m: m | {"column_count": 10**9, "row_stride": 10**9}, "the map message is damaged"),
    ("/morphology", lambda m: m | {"entities": [{"id": "robot"}]}, "scene message 0 is damaged"),
    ("/map", lambda m: m | {"cell_size": {"x": 10**400, "y": 0.1}}, "map message is damaged (OverflowError"),
    ("/map", lambda m: m | {"pose": m["pose"] | {"position": {"x": 1e300, "y": 0, "z": 0}}}, "beyond a map file's"),
    ("/map", lambda m: m | {"pose": m["pose"] | {"position": {"x": 0, "y": float("nan"), "z": 0}}}, "beyond a map"),
    ("/morphology", lambda m: _robot(m, lambda cubes: []), "scene message 0 is damaged (ValueError: 0 blocks, not "),
    ("/morphology", lambda m: _robot(m, lambda cubes: [_at(c, 10**400) for c in cubes]), "(OverflowError: int too"),
    ("/morphology", lambda m: _robot(m, lambda cubes: [_at(c, 1e300) for c in cubes]), "damaged (ValueError: a block"),
    ("/smorphi/step", lambda m: m | {"action": 5}, "action 5 is not three moves in 0..2"),
    ("/smorphi/step", lambda m: m | {"R1": 10**400}, "is not a finite number"),
    ("/smorphi/step", lambda m: m | {"step": 10**30}, "beyond any episode's 100,000"),
    ("/smorphi/step", lambda m: m | {"P_len": 10**30}, "beyond any coverage path's 250,000,000 tile moves"),
    ("/smorphi/step", lambda m: m | {"step": 0}, "step message 1 is damaged (step 0 does not follow step 0)"),
    ("/smorphi/step", lambda m: b"[       " * 5000 + b"]" * 5000, "a message on /smorphi/step is not the JSON smorphi"),
    ("/smorphi/step", lambda m: b"[" * 5000 + b"]" * 5000, "/smorphi/step holds more lists and objects than smorphi"),
])  # fmt: skip
def test_a_recording_whose_messages_are_damaged_is_one_line(tmp_path, capsys, topic, edit, message):
    env = recorded_env(tmp_path, max_steps=5)
    play(env, 0, np.random.default_rng(0))
    (source,) = episode_files(tmp_path / "episodes")
    bad = _tampered(source, tmp_path / "bad.mcap", topic, edit)
    code = main(["replay", str(bad), "--png", str(tmp_path / "r.png")])
    err = capsys.readouterr().err
    assert code == 1 and message in err and err.count("\n") == 1 and "Traceback" not in err, err
    assert not (tmp_path / "r.png").exists()


def test_a_recordings_text_is_shown_escaped_never_sent_to_the_terminal(tmp_path, capsys):
    """A map name or run name holding a newline or an escape sequence printed as it was (clearing the screen)."""
    env = recorded_env(tmp_path, max_steps=5)
    play(env, 0, np.random.default_rng(0))
    (source,) = episode_files(tmp_path / "episodes")
    odd = _tampered(source, tmp_path / "odd.mcap", "/smorphi/step", lambda m: m | {"map": "a\nb\x1b[2J"})
    assert main(["replay", str(odd)]) == 0
    out = capsys.readouterr().out
    assert "\x1b" not in out and "a\\nb\\x1b[2J" in out
    assert main(["replay", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "\x1b" not in out and "a\\nb\\x1b[2J" in out


def test_a_long_recorded_value_is_shown_shortened_with_its_length(tmp_path, capsys, monkeypatch):
    """A 10,000-character run or map name was printed whole, filling the screen for one field."""
    monkeypatch.setitem(META, "run", "r" * 9_000 + "-end")
    env = recorded_env(tmp_path, max_steps=5)
    play(env, 0, np.random.default_rng(0))
    (source,) = episode_files(tmp_path / "episodes")
    long = _tampered(source, tmp_path / "long.mcap", "/smorphi/step", lambda m: m | {"map": "m" * 10_000})
    assert main(["replay", str(long)]) == 0
    out = capsys.readouterr().out
    assert "-end (9,004 characters)" in out and "(10,000 characters)" in out
    assert max(len(line) for line in out.splitlines()) < 200, out
    assert main(["replay", str(tmp_path)]) == 0
    assert max(len(line) for line in capsys.readouterr().out.splitlines()) < 250


def test_a_recording_says_whether_its_episode_ran_to_its_end(tmp_path, capsys):
    """A run's last episodes end when its env closes: finished files whose steps replayed like a whole episode's;
    and a finished file that lost only its index read "the rest of the episode was lost", though no step was."""
    env = recorded_env(tmp_path, max_steps=40)
    play(env, 3, np.random.default_rng(0))  # a whole episode
    play(env, 4, np.random.default_rng(1), steps=12)  # then the run ends mid-episode
    env.close()
    whole, closed = sorted(episode_files(tmp_path / "episodes"), key=lambda f: len(read_episode(f).steps))[::-1]
    assert read_episode(whole).ended and read_episode(whole).cut_short is None
    assert read_episode(closed).cut_short == "cut short: the env was closed" and not read_episode(closed).truncated
    assert main(["replay", str(tmp_path / "episodes")]) == 0
    listing = capsys.readouterr().out.splitlines()
    assert sum(line.endswith("(cut short: the env was closed)") for line in listing) == 1
    assert main(["replay", str(closed)]) == 0
    assert "ended      cut short: the env was closed" in capsys.readouterr().out

    indexless = tmp_path / "indexless.mcap"
    data = whole.read_bytes()
    indexless.write_bytes(data[: len(data) - 40])  # the footer and magic gone, every chunk whole
    ep = read_episode(indexless)
    assert ep.truncated and ep.ended and ep.cut_short is None and len(ep.steps) == 41
    assert main(["replay", str(indexless)]) == 0
    assert "40 steps from a file cut short (every step of the episode is here)" in capsys.readouterr().out


def test_a_maps_yaw_leaves_the_grid_under_the_path_drawn_on_it():
    """The plans ignore the origin's yaw (as nav2 does); the grid was sent rotated by it, so in Foxglove a map with
    yaw 90 degrees lay a quarter turn away from the path and the robot drawn on it."""
    from smorphi_rl.maps import Map
    from smorphi_rl.recording.messages import grid_message

    grid = Map(np.zeros((4, 6), dtype=np.uint8), 0.1, origin=(1.0, 2.0, 1.5708), name="turned")
    pose = grid_message(grid, 0)["pose"]
    assert pose["position"] == {"x": 1.0, "y": 2.0, "z": 0.0}
    assert pose["orientation"] == {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
    assert grid.cell_of(1.0 + 0.55, 2.0 + 0.25) == (2, 5)  # the frame the path is drawn in: unrotated
