"""`train` and `evaluate-policy` refuse bad input with one line, before Ray starts."""

from __future__ import annotations

import io
import os
from pathlib import Path

import pytest
from cli_runs import PROMPT_ROWS

from smorphi_rl.cli import main
from smorphi_rl.cluster import local_cpus

ROOT = Path(__file__).resolve().parents[2]
MAP_1 = str(ROOT / "maps" / "map-1.yaml")


def run(capsys, *argv: str) -> tuple[int, str]:
    try:
        code = main(list(argv))
    except SystemExit as exc:  # argparse usage errors
        code = int(exc.code or 0)
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err  # exactly one line
    return code, err


@pytest.mark.parametrize(
    ("argv", "code", "message"),
    [
        (["--algo", "a3c"], 2, "invalid choice: 'a3c'"),
        (["--preset", "huge"], 2, "invalid choice: 'huge'"),
        (["--timesteps", "0"], 1, "--timesteps must be a positive integer, got 0"),
        (["--timesteps", "-10"], 1, "timesteps must be a positive integer, got -10"),
        (["--timesteps", "ten"], 2, "invalid int value: 'ten'"),
        (["--map", "/no/such/map.yaml"], 1, "map file not found: /no/such/map.yaml"),
        (["--map", "/no/such/*.yaml"], 1, "error: --map: map glob '/no/such/*.yaml' matches no map YAML"),
        (["--address", "127.0.0.1:1"], 1, "cannot reach a Ray cluster at 127.0.0.1:1"),
        (["--address", "nonsense"], 1, "--address must be HOST:PORT, 'auto' or ray://HOST:PORT"),
        (["--pretrained", "/no/such/checkpoint"], 1, "checkpoint not found: /no/such/checkpoint"),
        (["--env-runners", "-1"], 1, "env runners must be 0 (sample in the trial process) or more, got -1"),
        (["--envs-per-runner", "0"], 1, "--envs-per-runner must be a positive integer, got 0"),
        (["--reward", "greedy"], 2, "invalid choice: 'greedy'"),
        (["--eval-starts", "0"], 1, "--eval-starts must be a positive integer, got 0"),
        (["--select-starts", "-1"], 1, "--select-starts must be a non-negative integer (0: off), got -1"),
        (["--name", "../../etc"], 1, "is not a plain folder name"),
        (
            ["--map", "generate:mixed"],
            1,
            "so the run has no exact optimum to be measured against: name fixed floors "
            "with --eval-maps, or --eval-every 0",
        ),
        (["--eval-maps", "generate:rooms"], 1, "--eval-maps must be map files"),
        (["--eval-maps", "/no/such/map.yaml"], 1, "/no/such/map.yaml"),
        (["--eval-maps", MAP_1, MAP_1], 1, f"--eval-maps: {MAP_1} is named twice"),
    ],
)
def test_train_rejects_bad_input(capsys, tmp_path, argv, code, message):
    logs = tmp_path / "logs"
    got, err = run(capsys, "train", "--log-dir", str(logs), *argv)
    assert got == code and message in err and err.startswith("smorphi-rl")
    assert not logs.exists()  # nothing written by a refused run, not even its folder


def test_train_rejects_an_unwritable_log_dir(capsys, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    code, err = run(capsys, "train", "--log-dir", str(blocker / "logs"))
    assert code == 1 and f"log directory {blocker / 'logs'} is not writable" in err


def test_train_never_overwrites_a_run(capsys, tmp_path):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "summary.json").write_text("{}")
    code, err = run(capsys, "train", "--log-dir", str(tmp_path), "--name", "mine")
    assert code == 1 and "already exists: choose another --name" in err
    assert (tmp_path / "mine" / "summary.json").read_text() == "{}"


def test_evaluate_policy_rejects_bad_checkpoints(capsys, tmp_path):
    code, err = run(capsys, "evaluate-policy", "--checkpoint", str(tmp_path / "none"))
    assert code == 1 and "checkpoint not found" in err
    code, err = run(capsys, "evaluate-policy", "--checkpoint", str(tmp_path))
    assert code == 1 and "holds no RLlib checkpoint of ours" in err
    code, err = run(capsys, "evaluate-policy", "--checkpoint", str(tmp_path), "--episodes", "0")
    assert code == 1 and "--episodes must be in 1..10,000" in err


@pytest.mark.parametrize(
    ("argv", "code", "message"),
    [
        (["--pretrained", "/no/ckpt", "--maps", MAP_1], 1, "checkpoint not found: /no/ckpt"),
        (["--pretrained", "/no/ckpt", "--maps", "/no/map.yaml"], 1, "map file not found: /no/map.yaml"),
        (["--pretrained", "/no/ckpt", "--maps", MAP_1, "--timesteps", "0"], 1, "timesteps must be a positive integer"),
        (["--pretrained", "/no/ckpt", "--maps", MAP_1, "--algo", "a3c"], 2, "invalid choice: 'a3c'"),
        (["--pretrained", "/no/ckpt", "--maps", MAP_1, "--seeds", "-1"], 2, "expected a non-negative integer"),
        (["--pretrained", "/no/ckpt", "--maps", str(Path(MAP_1).parent)], 1, "checkpoint not found"),  # a folder: read
        (["--pretrained", "/no/ckpt", "--maps", "generate:mixed"], 1, "a generated floor has no exact optimum"),
        (["--pretrained", "/no/ckpt", "--maps", str(Path(MAP_1).parent / "designer")], 1, "holds no map YAML"),
    ],
)
def test_transfer_rejects_bad_input(capsys, tmp_path, argv, code, message):
    got, err = run(capsys, "transfer", "--log-dir", str(tmp_path), *argv)
    assert got == code and message in err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("sweep", "extra", "message"),
    [
        ("algorithms: [ppo]\nmaps: [{map}]\nseeds: [0]\nlr: 0.1\n", [], "key 'lr': unknown key"),
        (
            "algorithms: [ppo]\nmaps: [{map}]\nseeds: [0]\npretrained: /no/ckpt\n",
            [],
            "key 'pretrained': checkpoint '/no/ckpt' not found",
        ),
        ("algorithms: [ppo]\nmaps: [{map}]\nseeds: [0]\n", ["--resume"], "nothing to resume"),
        ("algorithms: [ppo]\nmaps: [{map}]\nseeds: [0]\n", ["--address", "127.0.0.1:1"], "cannot reach a Ray cluster"),
    ],
)
def test_sweep_rejects_bad_input_before_anything_starts(capsys, tmp_path, sweep, extra, message):
    config = tmp_path / "s.yaml"
    config.write_text(sweep.format(map=MAP_1))
    logs = tmp_path / "logs"
    code, err = run(capsys, "sweep", str(config), "--log-dir", str(logs), *extra)
    assert code == 1 and message in err and err.startswith("smorphi-rl: error: ")
    assert not logs.exists() or not list(logs.rglob("*"))


@pytest.mark.parametrize("command", ["train", "sweep"])
def test_a_missing_evaluated_map_is_named_before_any_optimum_is_computed(capsys, monkeypatch, tmp_path, command):
    monkeypatch.delenv("SMORPHI_RL_CACHE_DIR")  # exact optima would be cached under the log folder
    logs = tmp_path / "logs"
    if command == "train":
        argv = ["train", "--eval-maps", MAP_1, "/no/such/map.yaml"]
    else:
        config = tmp_path / "s.yaml"
        config.write_text(
            f"algorithms: [ppo]\nmaps: [{MAP_1}]\nseeds: [0]\nevaluation: {{maps: [{MAP_1}, /no/map.yaml]}}\n"
        )
        argv = ["sweep", str(config)]
    code, err = run(capsys, *argv, "--log-dir", str(logs))
    assert code == 1 and "not found" in err and "/no/" in err
    assert not logs.exists()


@pytest.mark.parametrize("extra", [[], ["--resume"]])
def test_a_sweep_into_a_log_dir_that_loops_is_one_line(capsys, tmp_path, extra):
    config = tmp_path / "s.yaml"
    config.write_text(f"algorithms: [ppo]\nmaps: [{MAP_1}]\nseeds: [0]\n")
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    code, err = run(capsys, "sweep", str(config), "--log-dir", str(loop), *extra)
    assert code == 1 and "cannot be used" in err


def test_sweep_file_missing(capsys, tmp_path):
    code, err = run(capsys, "sweep", str(tmp_path / "absent.yaml"))
    assert code == 1 and "no such sweep file" in err


def test_record_every_must_not_be_negative(capsys, tmp_path):
    code, err = run(capsys, "train", "--log-dir", str(tmp_path), "--record-every", "-1")
    assert code == 1 and "--record-every must be a non-negative integer" in err


def test_train_refuses_more_env_runners_than_the_local_ray_can_place(capsys, tmp_path):
    runners = 2 * local_cpus()  # 1 CPU for the trial and 0.5 a runner: one more than the local Ray has, on any machine
    got, err = run(capsys, "train", "--log-dir", str(tmp_path), "--env-runners", str(runners), "--timesteps", "1000")
    assert got == 1 and f"{runners} env runners need {local_cpus() + 1} CPUs" in err
    assert "use fewer --env-runners" in err
    assert not list(tmp_path.iterdir())  # the refused run's folder is gone again


def test_a_sweep_map_that_cannot_be_read_is_refused_before_ray(capsys, tmp_path):
    (tmp_path / "m.pgm").write_bytes(b"P5\n2 2\n255\n\x00\x00\x00\x00")  # every cell occupied: nothing to cover
    (tmp_path / "m.yaml").write_text("image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\n"
                                     "occupied_thresh: 0.65\nfree_thresh: 0.196\n")  # fmt: skip
    config = tmp_path / "s.yaml"
    config.write_text(f"algorithms: [ppo]\nmaps: [{tmp_path / 'm.yaml'}]\nseeds: [0]\n")
    code, err = run(capsys, "sweep", str(config), "--log-dir", str(tmp_path / "logs"))
    assert code == 1 and "has no free cell" in err and not (tmp_path / "logs").exists()


def test_a_run_whose_trial_reported_nothing_counts_as_never_started(tmp_path):
    """A trial folder with an empty result file (the first iteration failed) leaves nothing worth keeping; one
    reported row is a run whose folder stays."""
    from smorphi_rl.training.run import reported_any

    trial = tmp_path / "ppo-map-1_00000"
    trial.mkdir()
    assert not reported_any(tmp_path, "ppo")
    (trial / "result.json").write_text("")
    assert not reported_any(tmp_path, "ppo")
    (trial / "result.json").write_text('{"training_iteration": 1}\n')
    assert reported_any(tmp_path, "ppo") and not reported_any(tmp_path, "appo")


def _ray_daemon_of(pid: int) -> bool:
    """Whether `pid` has started Ray's GCS server (from /proc): ray.init is under way."""
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            parent = int(stat.read_text().rsplit(")", 1)[1].split()[1])
            if parent == pid and b"gcs_server" in (stat.parent / "cmdline").read_bytes():
                return True
        except (OSError, IndexError, ValueError):
            continue
    return False


def own_cache() -> dict[str, str]:
    """The environment a run sees that caches optima under its own --log-dir, not in the suite's shared folder."""
    from cli_runs import ray_env

    from smorphi_rl.protocol import CACHE_ENV

    return {k: v for k, v in ray_env().items() if k != CACHE_ENV}


@pytest.fixture(scope="module")
def cached_optimum(tmp_path_factory):
    """A log folder whose cache already holds map-1's optimum, so `train` starts Ray right after saying so."""
    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.maps import load_map
    from smorphi_rl.protocol import exact_optimum

    logs = tmp_path_factory.mktemp("cached") / "logs"  # the runs read its cache: `own_cache` drops the suite's
    env = EnvConfig.from_dict({"maps": [MAP_1]})
    exact_optimum(MAP_1, env.weights_on(load_map(MAP_1)), env.planning, logs / ".cache")
    return logs


@pytest.mark.parametrize("signame", ["SIGINT", "SIGTERM"])
def test_a_signal_while_ray_starts_stops_the_run(cached_optimum, signame):
    """While Ray started, SIGINT to a run a script had started in the background was ignored (the run trained its
    whole budget, exit 0) and SIGTERM reached Ray's own start-up handler (exit 15, nothing said): both now stop it,
    exit 130, one line, no folder."""
    import signal
    import subprocess
    import sys
    import time

    logs, name = cached_optimum, f"cut-{signame}"
    argv = ["train", "--timesteps", "4000", "--eval-every", "0", "--select-starts", "0", "--record-every", "0",
            "--env-runners", "0", "--envs-per-runner", "4", "--name", name, "--log-dir", str(logs)]  # fmt: skip

    def as_a_background_job() -> None:  # a script's `smorphi-rl train &`: its shell ignores SIGINT for it
        signal.signal(signal.SIGINT, signal.SIG_IGN)

    proc = subprocess.Popen([sys.executable, "-m", "smorphi_rl.cli", *argv], env=own_cache(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=as_a_background_job)  # fmt: skip
    assert proc.stderr is not None
    first = proc.stderr.readline()  # the optimum line, from the cache: Ray starts next and takes seconds
    deadline = time.monotonic() + 120
    while not (starting := _ray_daemon_of(proc.pid)) and time.monotonic() < deadline:  # inside ray.init
        time.sleep(0.05)
    time.sleep(0.3)
    proc.send_signal(getattr(signal, signame))
    _, err = proc.communicate(timeout=180)
    assert starting, "Ray's daemons never showed: the stop did not come as Ray started"
    assert "exact optimum" in first and proc.returncode == 130, (first, err)
    nothing = f"smorphi-rl: interrupted: stopped before the run's first report: nothing was kept ({logs / name} was"
    assert err.strip().splitlines()[-1] == f"{nothing} removed)" and "Traceback" not in err
    assert not (logs / name).exists()


def test_a_run_stopped_before_its_first_report_leaves_no_folder(cached_optimum):
    """Ctrl-C once Tune has made the trial's folder, before its first result: the run said 'checkpoints written
    so far are kept' and kept a folder of zero iterations; now it is an interrupted start, exit 130, no folder."""
    import signal
    import subprocess
    import sys
    import time

    logs, name = cached_optimum, "cut-before-report"
    argv = ["train", "--timesteps", "20000", "--eval-every", "0", "--select-starts", "0", "--record-every", "0",
            "--env-runners", "0", "--envs-per-runner", "4", "--name", name, "--log-dir", str(logs)]  # fmt: skip
    proc = subprocess.Popen([sys.executable, "-m", "smorphi_rl.cli", *argv], env=own_cache(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    deadline = time.monotonic() + 180
    while not (trial := list((logs / name).glob("ppo-*"))) and time.monotonic() < deadline:
        time.sleep(0.05)
    reported = any(f.stat().st_size for f in (logs / name).glob("ppo-*/result.json"))
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=180)
    assert trial, "Tune never made the trial's folder: the stop did not come between it and the first report"
    assert not reported, "the first iteration finished before the signal"
    nothing = f"stopped before the run's first report: nothing was kept ({logs / name} was removed)"
    assert proc.returncode == 130 and err.strip().splitlines()[-1] == f"smorphi-rl: interrupted: {nothing}", err
    assert not (logs / name).exists()


def test_a_run_whose_trial_failed_keeps_the_folder_its_error_line_names(tmp_path, monkeypatch):
    """The one line says where the full errors are: that folder stays, even when no iteration reported."""
    from contextlib import nullcontext

    from smorphi_rl import cluster
    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.training import run as run_module
    from smorphi_rl.training.config import TrainConfig

    def failing_fit(cfg, name, run_dir, *args):
        (run_dir / "ppo-x_00000").mkdir()
        (run_dir / "ppo-x_00000" / "error.txt").write_text("Traceback ...\nKeyError: 'mixed-1'\n")
        raise run_module.TrainingError(f"training failed: KeyError: 'mixed-1' (full errors under {run_dir})")

    monkeypatch.setattr(run_module, "_fit", failing_fit)
    monkeypatch.setattr(cluster, "ray_session", lambda address: nullcontext())
    cfg = TrainConfig(env=EnvConfig.from_dict({"maps": [MAP_1]}), eval_every=0, timesteps=1_000)
    with pytest.raises(run_module.TrainingError, match="full errors under") as failed:
        run_module.train(cfg, name="failed", log_dir=tmp_path, out=open(os.devnull, "w"))  # noqa: SIM115
    assert str(tmp_path / "failed") in str(failed.value)
    assert (tmp_path / "failed" / "ppo-x_00000" / "error.txt").is_file()


def test_train_fine_tunes_a_policy_in_the_env_it_was_trained_in():
    """`train --pretrained` takes the policy's layout, moves and reward (the designer's `floor`, 1/4/16) on the
    maps given; an option given on the command line still wins."""
    from smorphi_rl.cli import build_parser
    from smorphi_rl.cli.train import train_setup

    designer = str(ROOT / "smorphi_rl" / "policies" / "designer")
    algo, env = train_setup(
        build_parser().parse_args(["train", "--pretrained", designer, "--map", MAP_1, "--w2", "0.2"])
    )
    assert env.observation == "floor" and env.moves == (1, 4, 16) and env.w2 == 0.2 and algo == "ppo"
    assert [Path(m).name for m in env.maps] == ["map-1.yaml"]
    algo, plain = train_setup(build_parser().parse_args(["train", "--algo", "appo"]))
    assert plain.observation == "picture" and plain.moves == (1,) and algo == "appo"


@pytest.mark.parametrize("staged", [False, True])
def test_a_run_stopped_at_once_after_it_reported_says_what_its_folder_keeps(tmp_path, monkeypatch, capsys, staged):
    """A second Ctrl-C ends `train` at once, before its tables and summary: it printed only 'interrupted'. Tune
    stages a trial's result file elsewhere and copies it into the run's folder every few seconds: a run stopped
    between its first report and that copy (`staged`) lost its whole folder, recordings included."""
    from contextlib import nullcontext

    from smorphi_rl.training import run as run_module
    from smorphi_rl.training.result_keys import STEPS

    def fit(cfg, name, run_dir, callbacks, progress, stopper, late, resumed=None):
        trial = run_dir / f"{cfg.algo}-trial_00000"
        trial.mkdir()
        progress.status.out = io.StringIO()  # its progress line aside: the test reads stderr's last line
        progress.on_result({STEPS: 2_000})  # it reported once, to the driver
        (trial / "episode.mcap").write_bytes(b"recorded")
        if not staged:
            (trial / "result.json").write_text("{}\n")
        raise KeyboardInterrupt

    monkeypatch.setattr(run_module, "training_optima", lambda cfg, log_dir, out: {})
    monkeypatch.setattr(run_module.cluster, "ray_session", lambda address: nullcontext())
    monkeypatch.setattr(run_module, "_fit", fit)
    code, err = run(capsys, "train", "--log-dir", str(tmp_path / "logs"), "--name", "cut", "--eval-every", "0")
    assert code == 130
    kept = (f"{tmp_path / 'logs' / 'cut'} keeps what was written so far (episodes, logs, any checkpoint), but no "
            "tables or summary.json (`train --resume` with its --name continues it)")  # fmt: skip
    assert err.strip().splitlines()[-1] == f"smorphi-rl: interrupted: stopped at once; {kept}"
    assert (tmp_path / "logs" / "cut" / "ppo-trial_00000" / "episode.mcap").is_file()


def test_a_sweep_stopped_at_once_names_its_folder_and_the_resume(tmp_path, monkeypatch, capsys):
    """A second Ctrl-C ended `sweep` before its tables with a bare 'interrupted'."""
    from smorphi_rl.training import sweep as sweep_module

    root = Path(__file__).resolve().parents[2]
    config = tmp_path / "tiny.yaml"
    config.write_text(f"algorithms: [ppo]\nmaps: [{root / 'maps' / 'map-1.yaml'}]\nseeds: [0]\n")

    def cut(sweep, log_dir, address, resume):
        (Path(log_dir) / sweep.name).mkdir(parents=True)
        raise KeyboardInterrupt

    monkeypatch.setattr(sweep_module, "run_sweep", cut)
    code, err = run(capsys, "sweep", str(config), "--log-dir", str(tmp_path / "logs"))
    assert code == 130
    said = err.strip().splitlines()[-1]
    assert said.startswith(f"smorphi-rl: interrupted: stopped at once; {tmp_path / 'logs' / 'tiny'} keeps the trials")
    assert said.endswith(f"continue with `smorphi-rl sweep {config} --resume --log-dir {tmp_path / 'logs'}`")


@pytest.mark.parametrize("signame", ["SIGINT", "SIGTERM"])
def test_a_stop_as_the_run_writes_its_results_waits_for_them(tmp_path, monkeypatch, capsys, signame):
    """A Ctrl-C 1-2 s after the last bar (Ray shutting down, the tables being written) lost summary.json: a bare
    'interrupted', a second Ctrl-C's line, or (SIGTERM, once Ray had reset its handler) a kill without a word."""
    import signal
    from contextlib import contextmanager

    from smorphi_rl.training import run as run_module
    from smorphi_rl.training.result_keys import STEPS

    def fit(cfg, name, run_dir, callbacks, progress, stopper, late, resumed=None):
        (run_dir / f"{cfg.algo}-trial_00000").mkdir()
        progress.status.out = io.StringIO()
        progress.on_result({STEPS: cfg.timesteps})  # the whole budget, reported
        return 1.0

    writes = run_module.write_outputs

    def write_outputs(*args, **kwargs):
        signal.raise_signal(getattr(signal, signame))  # as the tables are written
        return writes(*args, **kwargs)

    @contextmanager
    def ray_session(address):
        yield
        signal.signal(signal.SIGTERM, signal.SIG_DFL)  # as Ray's shutdown leaves it: a SIGTERM then kills

    monkeypatch.setattr(run_module, "training_optima", lambda cfg, log_dir, out: {})
    monkeypatch.setattr(run_module.cluster, "ray_session", ray_session)
    monkeypatch.setattr(run_module, "_fit", fit)
    monkeypatch.setattr(run_module, "write_outputs", write_outputs)
    argv = ["train", "--log-dir", str(tmp_path / "logs"), "--name", "late", "--eval-every", "0", "--timesteps", "2000"]
    assert main(argv) == 130
    out, err = capsys.readouterr()
    assert (
        err.strip().splitlines()[-1]
        == "smorphi-rl: interrupted as the run ended: its tables and summary.json are whole"
    )
    assert (tmp_path / "logs" / "late" / "summary.json").is_file() and "PPO trained for 2,000 env steps" in out
    assert signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL  # SIGTERM is Ctrl-C again afterwards

    def twice(*args, **kwargs):  # a second stop as the results are written: at once, and said so
        signal.raise_signal(getattr(signal, signame))
        signal.raise_signal(getattr(signal, signame))
        return writes(*args, **kwargs)

    monkeypatch.setattr(run_module, "write_outputs", twice)
    assert main([*argv[:3], "--name", "twice", *argv[5:]]) == 130
    said = capsys.readouterr().err.strip().splitlines()[-1]
    assert said.startswith(f"smorphi-rl: interrupted: stopped at once; {tmp_path / 'logs' / 'twice'} keeps what")


@pytest.mark.parametrize("reported", [False, True])
def test_a_sweep_stopped_before_its_first_report_leaves_no_folder(tmp_path, monkeypatch, capsys, reported):
    """A Ctrl-C as Ray started left the sweep's folder (its claim, its copy of the file) with 'keeps the trials that
    finished ... continue with --resume', and the same command again was refused: the folder existed."""
    from smorphi_rl.training import sweep as sweep_module

    root = Path(__file__).resolve().parents[2]
    config = tmp_path / "tiny.yaml"
    config.write_text(f"algorithms: [ppo]\nmaps: [{root / 'maps' / 'map-1.yaml'}]\nseeds: [0]\n")

    def fit(sweep, exp, address, widest, optima, pending, points, progress, held, late):
        progress.reported = int(reported)
        raise KeyboardInterrupt

    monkeypatch.setattr(sweep_module, "training_optima", lambda cfg, log_dir, out: {})
    monkeypatch.setattr(sweep_module, "_fit", fit)
    code, err = run(capsys, "sweep", str(config), "--log-dir", str(tmp_path / "logs"))
    exp = tmp_path / "logs" / "tiny"
    assert code == 130 and exp.is_dir() is reported
    said = err.strip().splitlines()[-1]
    if reported:
        assert said.startswith(f"smorphi-rl: interrupted: stopped at once; {exp} keeps the trials")
    else:
        nothing = f"stopped before the sweep's first report: nothing was kept ({exp} was removed)"
        assert said == f"smorphi-rl: interrupted: {nothing}"


@pytest.mark.parametrize("signame", ["SIGINT", "SIGTERM"])
def test_a_stop_as_a_sweep_writes_its_tables_waits_for_them(tmp_path, monkeypatch, signame):
    """SIGTERM 1 s after the last trial (Ray shut down, the tables being written) killed the sweep without a word
    (exit 143) and without its tables."""
    import signal

    from smorphi_rl.training import sweep as sweep_module
    from smorphi_rl.training.sweep_config import load_sweep

    root = Path(__file__).resolve().parents[2]
    config = tmp_path / "tiny.yaml"
    config.write_text(f"algorithms: [ppo]\nmaps: [{root / 'maps' / 'map-1.yaml'}]\nseeds: [0]\n")
    written = []

    def fit(sweep, exp, address, widest, optima, pending, points, progress, held, late):
        held.enter_context(sweep_module.interrupts.stop_requests(late, again=True))
        signal.signal(signal.SIGTERM, signal.SIG_DFL)  # as Ray's shutdown leaves it
        return object(), None

    def outputs(exp, rows, optima=None):
        signal.raise_signal(getattr(signal, signame))
        written.append(exp)
        return {}

    monkeypatch.setattr(sweep_module, "training_optima", lambda cfg, log_dir, out: {})
    monkeypatch.setattr(sweep_module, "_fit", fit)
    monkeypatch.setattr(sweep_module, "read_sweep", lambda exp: [])
    monkeypatch.setattr(sweep_module, "write_trial_files", lambda *args, **kwargs: None)
    monkeypatch.setattr(sweep_module, "write_sweep_outputs", outputs)
    summary = sweep_module.run_sweep(load_sweep(config), tmp_path / "logs", None, False)
    assert written and summary.stop_held and signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL


@pytest.mark.slow
def test_a_killed_run_resumes_from_its_last_checkpoint_and_reports_the_whole_run(cached_optimum):
    """A train killed (SIGKILL: a job's time limit, the machine's memory) could only be started again from nothing.
    `--resume` continues it from its last checkpoint with our state; its curves and tables cover the whole run."""
    import json
    import signal
    import subprocess
    import sys
    import time

    from smorphi_rl.training.checkpoints import checkpoints_under

    logs, name = cached_optimum, "killed"
    argv = ["train", "--timesteps", "20000", "--checkpoint-every", "2", "--env-runners", "1", "--envs-per-runner",
            "4", "--eval-every", "2", "--eval-starts", "4", "--select-starts", "0", "--record-every", "0", "--name",
            name, "--log-dir", str(logs)]  # fmt: skip
    proc = subprocess.Popen([sys.executable, "-m", "smorphi_rl.cli", *argv], env=own_cache() | PROMPT_ROWS,
                            start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip

    def rows() -> int:
        return sum(len(p.read_text().splitlines()) for p in (logs / name).glob("ppo-*/result.json"))

    deadline = time.monotonic() + 300  # 10 iterations: under load the rows of the 5th lag, and the kill lands later
    while (len(checkpoints_under(logs / name)) < 2 or rows() < 5) and time.monotonic() < deadline:
        time.sleep(0.2)  # two checkpoints, and the rows of the first recorded in the run's folder
    os.killpg(proc.pid, signal.SIGKILL)  # the driver and its Ray at once, as a scheduler's kill
    proc.wait(timeout=60)
    assert rows() >= 5 and not (logs / name / "summary.json").exists(), "killed before two checkpoints, or at the end"
    again = subprocess.run([sys.executable, "-m", "smorphi_rl.cli", *argv], env=own_cache(), capture_output=True,
                           text=True, timeout=300)  # fmt: skip
    assert again.returncode == 1 and "stopped before it finished" in again.stderr and "add --resume" in again.stderr
    run = subprocess.run([sys.executable, "-m", "smorphi_rl.cli", *argv, "--resume"], env=own_cache(),
                         capture_output=True, text=True, timeout=600)  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    assert "resuming killed from its checkpoint of " in run.stderr
    summary = json.loads((logs / name / "summary.json").read_text())
    assert summary["env_steps"] >= 20000 and 0 < summary["resumed_at"] < 20000 and not summary["interrupted"]
    assert summary["iterations"] == 10  # the iterations before the checkpoint and after it, each once
    (trial,) = (logs / name).glob("ppo-*")  # the same trial's folder, the earlier files set aside in it
    assert (trial / "before-resume-1" / "result.json").is_file() and "resumed at" in run.stdout
    assert main(["train", *argv[1:], "--resume"]) == 1  # finished: nothing to continue
    (logs / name / "summary.json").unlink()  # killed as it wrote its tables: they are written again, nothing trained
    again = subprocess.run([sys.executable, "-m", "smorphi_rl.cli", *argv, "--resume"], env=own_cache(),
                           capture_output=True, text=True, timeout=300)  # fmt: skip
    assert again.returncode == 0, again.stderr[-3000:]
    rewritten = json.loads((logs / name / "summary.json").read_text())
    assert (rewritten["env_steps"], rewritten["iterations"]) == (summary["env_steps"], 10)  # not one iteration more
    assert not (trial / "before-resume-2").exists()
