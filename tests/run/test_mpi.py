"""Agents spread over the ranks of an MPI job (`dgtd.backends.mpi`): the same metrics bit for bit on 1 to 8 ranks
as a one-process run, a rank killed mid-run and the run resumed to the uninterrupted numbers, and what the runtime
does not run refused in one line with exit code 2 on every rank. Each test starts mpiexec on this machine only
(loopback), under a timeout; they need the mpi extra (pip install 'dgtd[mpi]'), which CI installs."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(
        shutil.which("mpiexec", path=str(Path(sys.executable).parent)) is None
        or subprocess.run([sys.executable, "-c", "import mpi4py"], capture_output=True).returncode != 0,
        reason="needs the mpi extra: pip install 'dgtd[mpi]' (mpi4py and MPICH)",
    ),
]

MPIEXEC = str(Path(sys.executable).parent / "mpiexec")
DGTD = [sys.executable, "-m", "dgtd.cli"]
# every algorithm whose agents spread over the ranks
SPREAD = ["dgtd", "pd-td", "consensus-td0", "consensus-tdrc", "td-tracking", "tdc-tracking", "local"]
CENTRALISED = ["td0", "gtd2", "tdc", "tdrc"]  # one learner: every rank runs it whole


def env(**extra) -> dict:
    e = dict(os.environ, MPIEXEC_TIMEOUT="240", DGTD_MPI_TIMEOUT="120", **extra)
    e.pop("PMI_SIZE", None)
    return e


def mpirun(ranks: int, *args, timeout: float = 300, **kw) -> subprocess.CompletedProcess:
    cmd = [MPIEXEC, "-n", str(ranks), *DGTD, *map(str, args)]
    return subprocess.run(cmd, env=env(), capture_output=True, text=True, timeout=timeout, **kw)


def alone(*args) -> subprocess.CompletedProcess:
    return subprocess.run([*DGTD, *map(str, args)], env=env(), capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("algorithm", SPREAD + CENTRALISED)
def test_every_algorithm_gives_the_one_process_numbers_on_1_to_4_ranks(tmp_path, algorithm):
    """paper-example-1 over random edges with receiver-dependent loss: metrics.csv identical, byte for byte, to a
    one-process run's, NumPy ranks to --backend numpy's and compiled ranks (the default) to the compiled kernels'
    (each rank drawing only its own agents' and links' numbers; 4 ranks on 5 agents: one rank holds two; a
    centralised learner is run whole by every rank)."""
    run = ["run", "paper-example-1", "--algorithm", algorithm, "-T", 1500, "--seeds", 2, "--no-plots"]
    run += ["--loss", "0.1,0.5,0,0.8,0.3", "--edge-prob", 0.7]
    for backend, ranks_list in {"numpy": (1, 2, 3, 4), "numba": (2, 3, 4)}.items():
        base = alone(*run, "--backend", backend, "--out", tmp_path / f"one-{backend}")
        assert base.returncode == 0, base.stderr
        for ranks in ranks_list:
            out = tmp_path / f"r{ranks}-{backend}"
            done = mpirun(ranks, *run, *(["--backend", "numpy"] if backend == "numpy" else []), "--out", out)
            assert done.returncode == 0, done.stderr
            assert (out / "metrics.csv").read_bytes() == (tmp_path / f"one-{backend}" / "metrics.csv").read_bytes()
            assert f"{backend} backend" in done.stdout and done.stdout.count("wrote ") == 1  # rank 0 alone says it


@pytest.mark.parametrize("algorithm", ["dgtd", "consensus-td0"])
@pytest.mark.parametrize(
    "links",
    [["--delay", 2, "--wake", 0.7, "--bits", 4], ["--bits", 3, "--top-k", 1, "--error-feedback"]],
    ids=["late-asleep-rounded", "top-k-error-feedback"],
)
def test_late_asleep_and_compressed_messages_across_ranks_give_the_one_process_numbers(tmp_path, algorithm, links):
    """The copies' channel (`dgtd.channels.Imperfect`) across ranks: each rank keeps the copies of the arcs into its
    own agents and the ranks gather them at block ends; over receiver-dependent loss, metrics.csv and summary.json's
    counts equal the one-process run's on 2 and 4 ranks."""
    import json

    run = ["run", "paper-example-1", "--algorithm", algorithm, "-T", 1500, "--seeds", 2, "--no-plots"]
    run += ["--loss", "0.1,0.5,0,0.8,0.3", *links, "--checkpoint-every", 700]
    for backend in ("numpy", "numba"):
        base = alone(*run, "--backend", backend, "--out", tmp_path / f"one-{backend}")
        assert base.returncode == 0, base.stderr
        one = json.loads((tmp_path / f"one-{backend}" / "summary.json").read_text())
        for ranks in (2, 4):
            out = tmp_path / f"r{ranks}-{backend}"
            done = mpirun(ranks, *run, "--backend", backend, "--out", out)
            assert done.returncode == 0, done.stderr
            assert (out / "metrics.csv").read_bytes() == (tmp_path / f"one-{backend}" / "metrics.csv").read_bytes()
            spread = json.loads((out / "summary.json").read_text())
            for key in ("w_last", "messages", "bits", "messages_per_agent", "bits_per_agent"):
                assert spread[key] == one[key], key


@pytest.mark.parametrize("algorithm", ["dgtd", "consensus-td0", "tdc-tracking"])
def test_asynchronous_with_staleness_0_gives_the_synchronous_numbers(tmp_path, algorithm):
    """--staleness 0 makes every rank wait for its neighbours' message of its own step: the asynchronous runtime's
    messages (non-blocking sends, the inboxes, the ghosts written from them) then give the one-process numbers byte for
    byte, and every age counted is 0."""
    import json

    run = ["run", "paper-example-1", "--algorithm", algorithm, "-T", 1500, "--seeds", 2, "--no-plots"]
    run += ["--loss", "0.1,0.5,0,0.8,0.3", "--edge-prob", 0.7]
    base = alone(*run, "--backend", "numpy", "--out", tmp_path / "one")
    assert base.returncode == 0, base.stderr
    for ranks in (2, 4):
        out = tmp_path / f"r{ranks}"
        done = mpirun(ranks, *run, "--asynchronous", "--staleness", 0, "--out", out)  # the reference, by itself
        assert done.returncode == 0, done.stderr
        assert (out / "metrics.csv").read_bytes() == (tmp_path / "one" / "metrics.csv").read_bytes()
        ages = json.loads((out / "summary.json").read_text())["message_ages"]
        assert ages["max"] == 0 and ages["used"] == ages["steps"]["0"] > 0
        assert (out / "message_ages.csv").read_text() == f"age_steps,count\n0,{ages['used']}\n"


def test_asynchronous_ranks_do_not_wait_and_say_how_old_their_messages_were(tmp_path):
    """4 ranks on this machine's 2 cores take turns, so without waiting their agents use older messages: the ages
    are counted (one per ghost and step), staleness S bounds them, and a run whose ages stay within 2 steps ends
    where a synchronous one does: garnet's tail-averaged error under 1 % (measured 0.27-0.29 % against 0.27 % for
    the one-process run: at the ends of the run the steps are small, and a message 2 steps old differs from the
    current one by O(step))."""
    import json

    run = ["run", "garnet", "-T", 20_000, "--no-plots", "--asynchronous"]
    summaries = {}
    for name, extra in {"free": [], "bounded": ["--staleness", 2]}.items():
        done = mpirun(4, *run, *extra, "--out", tmp_path / name)
        assert done.returncode == 0, done.stderr
        summaries[name] = json.loads((tmp_path / name / "summary.json").read_text())
    free, bounded = (summaries[k]["message_ages"] for k in ("free", "bounded"))
    # a ring of 10 agents on 4 ranks holding 2, 3, 2 and 3 neighbours on the ring: each rank hears two agents of
    # other ranks (8 ghosts a step) and has two neighbouring ranks (8 messages a step)
    assert free["used"] == bounded["used"] == 20_000 * 8
    assert free["messages_received"] == bounded["messages_received"] == 20_000 * 8
    assert free["max"] > 2 and bounded["max"] <= 2
    assert summaries["bounded"]["max_error_tail"] < 0.01


def test_garnet_and_a_users_env_on_two_ranks(tmp_path):
    chain = Path(__file__).resolve().parents[1] / "envs" / "chain.py"
    for name, args in {
        "garnet": ["garnet"],
        "env": ["--env", f"{chain}:make_chain", "--features", "one-hot", "--agents", 4],
    }.items():
        for backend in ("numpy", "numba"):
            run = ["run", *args, "-T", 2000, "--seeds", 2, "--no-plots", "--backend", backend]
            base = alone(*run, "--out", tmp_path / f"{name}-one-{backend}")
            done = mpirun(2, *run, "--out", tmp_path / f"{name}-two-{backend}")
            assert base.returncode == 0 and done.returncode == 0, done.stderr
            one, two = (tmp_path / f"{name}-{k}-{backend}" / "metrics.csv" for k in ("one", "two"))
            assert one.read_bytes() == two.read_bytes()


@pytest.mark.parametrize("algorithm", ["dgtd", "consensus-td0"])
def test_eight_ranks_over_late_asleep_rounded_and_markovian_samples(tmp_path, algorithm):
    """garnet's 10 agents on 8 ranks (most ranks hold one agent, every link crosses ranks), Markovian samples of
    each agent's own chain, random edges, bursty loss, late, asleep and rounded messages: the numbers of one process
    (consensus TD(0)'s Metropolis weights need what the ghosts heard, drawn by each rank itself)."""
    run = ["run", "garnet", "--algorithm", algorithm, "-T", 800, "--seeds", 2, "--no-plots", "--sampling", "markov"]
    run += ["--edge-prob", 0.8, "--loss", 0.2, "--burst", 3, "--delay", 2, "--wake", 0.8, "--bits", 6]
    for backend in ("numpy", "numba"):
        base = alone(*run, "--backend", backend, "--out", tmp_path / f"one-{backend}")
        assert base.returncode == 0, base.stderr
        done = mpirun(8, *run, "--backend", backend, "--out", tmp_path / f"eight-{backend}")
        assert done.returncode == 0, done.stderr
        eight, one = (tmp_path / f"{k}-{backend}" / "metrics.csv" for k in ("eight", "one"))
        assert eight.read_bytes() == one.read_bytes()


def test_a_graph_numbered_at_random_is_split_in_storage_order(tmp_path):
    """300 agents on a ring numbered at random: the ranks take blocks of the reverse Cuthill-McKee order (which
    finds the ring again), and the numbers are still the one-process run's."""
    import numpy as np

    label = np.random.default_rng(0).permutation(300)
    (tmp_path / "ring.txt").write_text("".join(f"{label[i]} {label[(i + 1) % 300]}\n" for i in range(300)))
    toml = tmp_path / "big.toml"
    toml.write_text(
        f'[problem]\nscenario = "garnet"\nparams = {{ n_agents = 300 }}\n[network]\ngraph = "{tmp_path / "ring.txt"}"\n'
    )
    run = ["run", toml, "-T", 300, "--seeds", 2, "--no-plots"]
    base = alone(*run, "--out", tmp_path / "one")  # compiled, as the ranks
    done = mpirun(3, *run, "--out", tmp_path / "three")
    assert base.returncode == 0 and done.returncode == 0, done.stderr
    assert (tmp_path / "one" / "metrics.csv").read_bytes() == (tmp_path / "three" / "metrics.csv").read_bytes()


def _ranks_of(tag: str) -> dict[int, int]:
    """{rank: pid} of the ranks started with DGTD_TEST_TAG=tag."""
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            environ = (entry / "environ").read_bytes().split(b"\0")
        except OSError:
            continue
        if f"DGTD_TEST_TAG={tag}".encode() in environ:
            for item in environ:
                if item.startswith(b"PMI_RANK="):
                    found[int(item.split(b"=")[1])] = int(entry.name)
    return found


def _wait_for_a_checkpoint(job: subprocess.Popen, out: Path, name: str = "checkpoint.npz") -> None:
    deadline = time.monotonic() + 120
    while not (out / name).exists():
        assert time.monotonic() < deadline and job.poll() is None, "no checkpoint written"
        time.sleep(0.1)


def _interrupted(cmd: list, out: Path, checkpoint: str = "checkpoint.npz", group: bool = True) -> tuple[int, str]:
    """(exit code, stderr) of ``cmd`` sent SIGINT once its first checkpoint is written: to its process group, as a
    terminal's Ctrl-C, or to the launcher alone; every process it started is killed if it outlives 30 s."""
    job = subprocess.Popen(
        cmd,
        env=env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # as a terminal's shell leaves it
    )
    try:
        _wait_for_a_checkpoint(job, out, checkpoint)
        (os.killpg if group else os.kill)(job.pid, signal.SIGINT)
        _, err = job.communicate(timeout=30)
    finally:
        if job.poll() is None:
            os.killpg(job.pid, signal.SIGKILL)
    return job.returncode, err


def _killed_after_a_checkpoint(run: list, out: Path, ranks: int = 2) -> list:
    """Start ``dgtd run RUN --out OUT`` on ``ranks`` ranks, SIGKILL rank 1 once a checkpoint is written, check that
    mpiexec ends the job (no rank left waiting) with nothing finished; returns the command."""
    tag = f"kill{os.getpid()}{out.name}"
    cmd = [MPIEXEC, "-n", str(ranks), *DGTD, *map(str, run), "--out", str(out)]
    job = subprocess.Popen(cmd, env=env(DGTD_TEST_TAG=tag), stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        _wait_for_a_checkpoint(job, out)
        time.sleep(0.5)
        os.kill(_ranks_of(tag)[1], signal.SIGKILL)
        job.wait(timeout=120)
    finally:
        job.kill()
    assert job.returncode != 0 and not (out / "summary.json").exists()
    return cmd


def test_a_rank_killed_mid_run_loses_nothing_checkpointed(tmp_path):
    """SIGKILL to rank 1 after the first checkpoint, and the same command run again on two ranks resumes from the
    checkpoint and ends with the numbers of an uninterrupted one-process run, byte for byte."""
    out = tmp_path / "run"
    run = ["run", "garnet", "-T", 60_000, "--seeds", 2, "--no-plots", "--checkpoint-every", 3000, "--backend", "numpy"]
    cmd = _killed_after_a_checkpoint(run, out)
    resumed = subprocess.run(cmd, env=env(), capture_output=True, text=True, timeout=300)  # the same command again
    assert resumed.returncode == 0, resumed.stderr
    assert "resuming" in resumed.stdout
    whole = alone(*run, "--backend", "numpy", "--out", tmp_path / "whole")
    assert whole.returncode == 0
    assert (out / "metrics.csv").read_bytes() == (tmp_path / "whole" / "metrics.csv").read_bytes()


def test_a_run_killed_on_two_ranks_resumes_on_three_and_in_one_process_with_the_same_numbers(tmp_path):
    """Each rank writes a shard of the checkpoint (its agents' rows, the arcs into them, its agents' Markov chains:
    checkpoint.npz, rank 0's, names the others'); killed on 2 ranks, the same command on 3 ranks, and the run
    resumed by one process, each take their agents' rows by id and end with the uninterrupted numbers."""
    out = tmp_path / "run"
    run = ["run", "garnet", "-T", 30_000, "--seeds", 2, "--no-plots", "--checkpoint-every", 3000]
    run += ["--sampling", "markov", "--loss", 0.3, "--burst", 2]
    cmd = _killed_after_a_checkpoint(run, out)
    shards = sorted(p.name for p in out.glob("checkpoint*.npz"))
    assert len(shards) == 2 and shards[0].endswith(".1.npz") and shards[1] == "checkpoint.npz", shards
    shutil.copytree(out, tmp_path / "alone")
    cmd[cmd.index("-n") + 1] = "3"
    resumed = subprocess.run(cmd, env=env(), capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0 and "resuming" in resumed.stdout, resumed.stderr
    kept = sorted(p.name for p in out.glob("checkpoint*"))  # the state at the end alone, to extend the run from
    assert kept == ["checkpoint.30000.1.npz", "checkpoint.30000.2.npz", "checkpoint.npz"], kept
    alone_resumed = alone(*run, "--out", tmp_path / "alone")
    assert alone_resumed.returncode == 0 and "resuming" in alone_resumed.stdout, alone_resumed.stderr
    whole = alone(*run, "--out", tmp_path / "whole")  # compiled, as the ranks
    assert whole.returncode == 0
    expected = (tmp_path / "whole" / "metrics.csv").read_bytes()
    assert (out / "metrics.csv").read_bytes() == expected
    assert (tmp_path / "alone" / "metrics.csv").read_bytes() == expected


CHUNKED = {
    "small-world": ["--graph", "small-world", "--mean-degree", 4, "--rewire", 0.3],
    "sparse-random": ["--graph", "sparse-random", "--mean-degree", 9],
    "geometric": ["--graph", "geometric", "--mean-degree", 8, "--graph-seed", 1],
}


@pytest.mark.parametrize("graph", CHUNKED)
def test_generated_tasks_on_chunked_graphs_give_the_same_bytes_on_1_2_3_and_8_ranks(tmp_path, graph):
    """garnet sized by --agents on each keyed chunked graph, links up with probability 0.8: metrics.csv byte for byte
    a one-process run's on 1, 2, 3 and 8 ranks (compiled ranks, as one compiled process)."""
    run = ["run", "garnet", "--agents", 64, *CHUNKED[graph], "-T", 400, "--seeds", 2, "--no-plots"]
    base = alone(*run, "--out", tmp_path / "one")
    assert base.returncode == 0, base.stderr
    expected = (tmp_path / "one" / "metrics.csv").read_bytes()
    for ranks in (1, 2, 3, 8):
        done = mpirun(ranks, *run, "--out", tmp_path / f"r{ranks}")
        assert done.returncode == 0, done.stderr
        assert (tmp_path / f"r{ranks}" / "metrics.csv").read_bytes() == expected, ranks


def test_a_run_on_a_chunked_graph_killed_on_four_ranks_resumes_on_two_with_the_same_numbers(tmp_path):
    """A garnet run of 40 agents on a geometric graph, rank 1 of 4 killed after a checkpoint: the same command on 2
    ranks resumes from the 4 shards and ends with the uninterrupted run's numbers, byte for byte."""
    out = tmp_path / "run"
    run = ["run", "garnet", "--agents", 40, *CHUNKED["geometric"], "-T", 40_000, "--seeds", 2, "--no-plots"]
    run += ["--checkpoint-every", 2000, "--loss", 0.2]
    cmd = _killed_after_a_checkpoint(run, out, ranks=4)
    assert len(list(out.glob("checkpoint*.npz"))) == 4
    cmd[cmd.index("-n") + 1] = "2"
    resumed = subprocess.run(cmd, env=env(), capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0 and "resuming" in resumed.stdout, resumed.stderr
    whole = alone(*run, "--out", tmp_path / "whole")
    assert whole.returncode == 0, whole.stderr
    assert (out / "metrics.csv").read_bytes() == (tmp_path / "whole" / "metrics.csv").read_bytes()


def test_many_agents_rows_are_written_by_the_ranks_that_hold_them(tmp_path):
    """16 000 agents x 8 seeds x 8 features (past `GATHER_MAX`): rank 0 gathers no agent's rows; each rank writes its
    agents' file (agents.npz, agents.1.npz, ...), and `read_results` puts them together into exactly the one-process
    run's per-agent arrays and traces, the worst errors the same numbers, the consensus error to rounding (summed up
    the agents' tree, where one process takes the plain sum), the final table the same lines."""
    import json

    import numpy as np

    from dgtd.run.results import read_results

    run = ["run", "garnet", "--agents", 16_000, "--seeds", 8, "-T", 20, "--checkpoints", 2, "--no-plots"]
    base = alone(*run, "--no-progress", "--out", tmp_path / "one")
    assert base.returncode == 0, base.stderr
    one = read_results(tmp_path / "one")
    table = lambda out: [line for line in out.splitlines() if not line.startswith(("wrote", "resuming"))][1:]  # noqa: E731
    for ranks in (2, 3):
        out = tmp_path / f"r{ranks}"
        done = mpirun(ranks, *run, "--no-progress", "--out", out)
        assert done.returncode == 0, done.stderr
        parts = json.loads((out / "summary.json").read_text())["per_agent"]["parts"]
        assert parts == ["agents.npz", *(f"agents.{r}.npz" for r in range(1, ranks))]
        assert all((out / name).is_file() for name in parts)
        assert (out / "metrics.csv").read_bytes() == (tmp_path / "one" / "metrics.csv").read_bytes()
        spread = read_results(out)
        for name in one.summary["per_agent"]["arrays"]:  # (theta*, mu*: solved by each process, its own threads)
            exact = not name.endswith("_star")
            assert np.array_equal(spread.summary[name], one.summary[name]) or not exact, name
            np.testing.assert_allclose(spread.summary[name], one.summary[name], rtol=1e-9, atol=1e-9, err_msg=name)
        for name in ("agent_error_last", "agent_error_avg"):
            assert np.array_equal(spread.trajectory[name], one.trajectory[name]), name
        for name in (k for k in one.summary if k.startswith("max_")):
            assert spread.summary[name] == one.summary[name], name
        np.testing.assert_allclose(spread.summary["consensus_last"], one.summary["consensus_last"], rtol=1e-12)
        assert table(done.stdout) == table(base.stdout)


def test_an_asynchronous_run_resumes_with_its_message_ages(tmp_path):
    """The same after-a-kill resume of an asynchronous run: the ages counted before the checkpoint come back with
    it, so that every step's ghosts are counted once (garnet's ring of 10 agents on 2 ranks: 2 ghosts on each, 4 a
    step) and the run still converges."""
    import json

    out = tmp_path / "run"
    T = 60_000
    run = ["run", "garnet", "-T", T, "--no-plots", "--checkpoint-every", 3000, "--asynchronous", "--staleness", 2]
    cmd = _killed_after_a_checkpoint(run, out)
    resumed = subprocess.run(cmd, env=env(), capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0 and "resuming" in resumed.stdout, resumed.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["message_ages"]["used"] == 4 * T and summary["message_ages"]["max"] <= 2
    assert summary["max_error_tail"] < 0.01  # as in the test above


@pytest.mark.parametrize(
    "args, words",
    [
        (["paper-example-1", "--delay", "2", "--asynchronous"], "not with --asynchronous"),
        (["paper-example-1", "--backend", "numba", "--asynchronous"], "NumPy reference"),
        (["garnet", "--agents", "1000", "--seeds", "10000000"], "the 2 ranks on this machine need about"),
    ],
)
def test_what_the_runtime_does_not_run_is_one_line_and_exit_2_on_every_rank(tmp_path, args, words):
    done = mpirun(2, "run", *args, "-T", 100, "--out", tmp_path / "o")
    assert done.returncode == 2
    errors = [line for line in done.stderr.splitlines() if line.startswith("dgtd:")]
    assert len(errors) == 1 and words in errors[0]  # rank 0's line only


def test_only_run_learn_and_networked_spread_over_ranks(tmp_path):
    """Another command under mpiexec would run once on every rank, each writing the same files: refused."""
    cmd = [MPIEXEC, "-n", "2", *DGTD, "compare", "paper-example-1", "-T", "100", "--out", str(tmp_path / "c")]
    done = subprocess.run(cmd, env=env(), capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert [line for line in done.stderr.splitlines() if line.startswith("dgtd:")] == [
        "dgtd: error: under mpiexec only `dgtd run`, `dgtd learn` and `dgtd networked` spread their agents over the "
        "ranks; run `dgtd compare` in one process"
    ]


def test_ranks_started_by_dgtd_run_itself(tmp_path):
    """`dgtd run --ranks 2` starts the mpi extra's mpiexec: the numbers of `mpiexec -n 2 dgtd run`, which are one
    process's; a host file naming this machine works."""
    run = ["run", "paper-example-1", "-T", 500, "--seeds", 2, "--no-plots"]
    base = alone(*run, "--out", tmp_path / "one")
    (tmp_path / "hosts.txt").write_text("localhost:2\n")
    for name, extra in {"ranks": [], "hosts": ["--hosts", tmp_path / "hosts.txt"]}.items():
        done = alone(*run, "--ranks", 2, *extra, "--out", tmp_path / name)
        assert base.returncode == 0 and done.returncode == 0, done.stderr
        assert (tmp_path / name / "metrics.csv").read_bytes() == (tmp_path / "one" / "metrics.csv").read_bytes()
        assert done.stdout.count("wrote ") == 1


@pytest.mark.parametrize("to", ["group", "launcher"])
def test_ctrl_c_ends_every_rank_at_once_and_keeps_the_checkpoint(tmp_path, to):
    """Ctrl-C (SIGINT to the terminal's process group) reaches a rank only where it runs Python; a rank inside a
    collective would wait for it until the watchdog's timeout. The interrupted rank ends the job (MPI_Abort): every
    process is gone within seconds, the launcher exits 130 as an interrupted run does, the checkpoint is whole, and
    the same command again continues from it. SIGINT to the `dgtd run --ranks` launcher alone does the same (the
    ranks ran on, and the launcher ended in a TimeoutExpired traceback, exit 1)."""
    out = tmp_path / "run"
    cmd = [*DGTD, "run", "garnet", "-T", "100000", "--ranks", "2", "--checkpoint-every", "5000", "--out", str(out)]
    code, err = _interrupted(cmd, out, group=to == "group")
    assert code == 130 and "dgtd: interrupted" in err, err
    assert not (out / "summary.json").exists()
    cut = subprocess.run([*cmd[:5], "-T", "20000", *cmd[7:]], env=env(), capture_output=True, text=True, timeout=300)
    assert cut.returncode == 2 and "checkpoint of another run" in cut.stderr  # not thrown away: another config
    again = subprocess.run(cmd, env=env(), capture_output=True, text=True, timeout=600)
    assert again.returncode == 0 and "resuming" in again.stdout, again.stderr


@pytest.mark.skipif(shutil.which("ssh") is None, reason="mpiexec reaches other hosts over ssh, not installed here")
def test_a_host_that_cannot_be_reached_is_one_line_and_exit_2(tmp_path):
    """127.0.0.2 is this machine's loopback, where no ssh server listens: refused before any rank starts."""
    (tmp_path / "hosts").write_text("localhost:1\n127.0.0.2:1\n")
    run = ["run", "paper-example-1", "-T", 100, "--ranks", 2]
    done = alone(*run, "--hosts", tmp_path / "hosts", "--out", tmp_path / "o")
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and "host 127.0.0.2 of" in done.stderr and "cannot be reached" in done.stderr
    assert not (tmp_path / "o").exists()


def test_more_ranks_than_agents_is_refused(tmp_path):
    done = mpirun(6, "run", "paper-example-1", "-T", 100, "--out", tmp_path / "o")
    assert done.returncode == 2
    assert "6 ranks for 5 agents" in done.stderr


def _one_process_bytes_on_2_and_3_ranks(tmp_path, run: list) -> None:
    """``run`` in one process, then with --ranks 2 and 3: metrics.csv and policies.npz the same, byte for byte."""
    base = alone(*run, "--out", tmp_path / "one")
    assert base.returncode == 0, base.stderr
    for ranks in (2, 3):
        done = alone(*run, "--ranks", ranks, "--out", tmp_path / f"r{ranks}")
        assert done.returncode == 0, done.stderr
        for name in ("metrics.csv", "policies.npz"):
            assert (tmp_path / f"r{ranks}" / name).read_bytes() == (tmp_path / "one" / name).read_bytes(), (ranks, name)


LEARN = ["learn", "pull-away", "--seeds", 2, "--loss", 0.2, "--no-plots", "--no-progress"]


@pytest.mark.parametrize(
    "extra",
    [
        [],
        ["--values", "action"],
        ["--actor", "centralised", "--batch", 4],
        ["--backend", "numpy"],
        ["--team-reward", "neighbourhood", "--batch", 2],
    ],
)
def test_learners_on_ranks_are_one_process_bit_for_bit(tmp_path, extra):
    """`dgtd learn --ranks R`: each rank holds its agents' actors, critics and reward estimates (4 agents on 3 ranks:
    one rank holds two); their actions, messages and rows gathered in agent order, the policies and metrics are one
    process's, byte for byte, on 2 and 3 ranks, over links that lose 20 % of messages (compiled, and NumPy)."""
    run = [*LEARN, "-T", 800, *extra]
    _one_process_bytes_on_2_and_3_ranks(tmp_path, run)


SPARSE = ["learn", "factored", "--agents", 12, "--seeds", 2, "--loss", 0.2, "--burst", 3, "--no-plots", "--no-progress"]


@pytest.mark.parametrize(
    "extra",
    [
        [],
        ["--algorithm", "td-tracking", "--backend", "numpy", "--edge-prob", 0.7],
        ["--backend", "jax", "--batch", 2],
    ],
)
def test_learners_on_a_sparse_graph_hear_by_the_halo_bit_for_bit(tmp_path, extra):
    """12 agents on a ring (sparse: a rank's share is its agents, a ghost each side): each rank delivers only the
    arcs into its agents, its ghosts' messages by the run's halo exchange (`dgtd.backends.mpi.Partition`), their
    counts for Metropolis weights from the draws of the arcs into them (td-tracking's mix, Zhang et al.'s regression),
    each link's bursty losses keyed by its agents, and (--edge-prob) the edges up those it draws, each with its own
    probability: the policies and metrics one process's, byte for byte, on 2 and 3 ranks (compiled, NumPy, JAX)."""
    _one_process_bytes_on_2_and_3_ranks(tmp_path, [*SPARSE, "-T", 400, *extra])


@pytest.mark.parametrize("again_on, task", [(2, LEARN), (3, LEARN), (3, SPARSE)])
def test_learners_interrupted_on_2_ranks_resume_to_the_uninterrupted_numbers(tmp_path, again_on, task):
    """Ctrl-C to a `dgtd learn --ranks 2` job after a checkpoint: every process ends, every rank's shard of the
    checkpoint is whole (the run's checkpoint format); the same command again, on 2 ranks or on 3 (each takes its
    agents' rows, and the links' states of the arcs into them, by id from whichever shard holds them), resumes and
    ends with the uninterrupted one-process run's metrics, byte for byte (on the sparse ring, bursty losses: each
    link's state is its own)."""
    run = [*task, "-T", 30000, "--checkpoint-every", 1000]
    out = tmp_path / "cut"
    code, err = _interrupted([*DGTD, *map(str, run), "--ranks", "2", "--out", str(out)], out, "learning-checkpoint.npz")
    assert code == 130 and not (out / "summary.json").exists(), err
    again = alone(*run, "--ranks", again_on, "--out", out)
    assert again.returncode == 0 and "resuming" in again.stdout, again.stderr
    whole = alone(*run, "--out", tmp_path / "whole")
    assert whole.returncode == 0, whole.stderr
    assert (out / "metrics.csv").read_bytes() == (tmp_path / "whole" / "metrics.csv").read_bytes()


NETWORKED = ["networked", "--seeds", 2, "--every", 100, "--rollouts", 10, "--no-plots", "--no-progress"]


@pytest.mark.parametrize(
    "task",
    [["wireless-access", "-T", 300, "--loss", 0.2], ["random-networked", "-T", 200, "--hops", 2]],
)
def test_networked_learners_on_ranks_are_one_process_bit_for_bit(tmp_path, task):
    """`dgtd networked --ranks R`: each rank holds its agents' actors and critics and draws their actions; the
    actions of a step and the values of an episode gathered, metrics.csv (every evaluation) and policies.npz are one
    process's, byte for byte, on 2 and 3 ranks (24 users over lossy messages; a ring of 10 agents, two hops)."""
    run = [*NETWORKED, *task]
    _one_process_bytes_on_2_and_3_ranks(tmp_path, run)
    refused = alone(*run, "--ranks", 2, "--checkpoint-every", 50, "--out", tmp_path / "cp")
    assert refused.returncode == 2 and "keeps no checkpoint yet" in refused.stderr
