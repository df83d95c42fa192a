"""Inputs kept aside from the mending of the new user's and the independent check's findings, of the same kinds: each
gets one line and exit code 2, or a correct run with its results; never a traceback, a hang, an exit 0 without
results, or a silently different answer."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from helpers import one_line_error

ENVS = Path(__file__).resolve().parents[1] / "envs"
FAST = ("-T", "100", "--backend", "numpy", "--no-plots", "--no-progress")


def mrp(path: Path, **arrays) -> Path:
    P = np.array([[0.5, 0.5, 0.0], [0.0, 0.5, 0.5], [0.5, 0.0, 0.5]])
    base = dict(P=P, R=np.ones((3, 3)), Phi=np.eye(3)[:, :2] + 0.2, gamma=0.9)
    np.savez(path, **{**base, **arrays})
    return path


def features_file(tmp_path: Path, body: str) -> str:
    (tmp_path / "feats.py").write_text(f"import numpy as np\n\n\ndef features(states):\n    {body}\n")
    return f"{tmp_path / 'feats.py'}:features"


# (name, how to make the command's arguments from tmp_path, the words of the one line)
REFUSED = {
    "gamma nan": (lambda t: ["--problem", mrp(t / "p.npz", gamma=np.nan)], ["gamma"]),
    "gamma as text": (lambda t: ["--problem", mrp(t / "p.npz", gamma=np.array("0.9"))], ["gamma"]),
    "P negative": (
        lambda t: ["--problem", mrp(t / "p.npz", P=np.array([[1.5, -0.5, 0], [0, 1, 0], [0, 0, 1.0]]))],
        ["P"],
    ),
    "R infinite": (lambda t: ["--problem", mrp(t / "p.npz", R=np.full((3, 3), np.inf))], ["R"]),
    "Phi nan": (lambda t: ["--problem", mrp(t / "p.npz", Phi=np.full((3, 2), np.nan))], ["Phi"]),
    "unknown array": (lambda t: ["--problem", mrp(t / "p.npz", Rr=np.ones(3))], ["'Rr'"]),
    "sigma negative": (lambda t: ["--problem", mrp(t / "p.npz", sigma=-1.0)], ["sigma"]),
    "sigma nan": (lambda t: ["--problem", mrp(t / "p.npz", sigma=np.nan)], ["sigma must be a finite number"]),
    "terminal inf": (
        lambda t: ["--problem", mrp(t / "p.npz", terminal=np.array([np.inf, 0, 0]))],
        ["terminal holds inf"],
    ),
    "problem a directory": (lambda t: ["--problem", t], ["is a directory"]),
    "problem empty": (lambda t: ["--problem", _write(t / "e.npz", b"")], ["e.npz"]),
    "problem truncated": (lambda t: ["--problem", _write(t / "c.npz", mrp(t / "p.npz").read_bytes()[:100])], ["c.npz"]),
    "edge list with text": (lambda t: ["paper-example-1", "--graph", _write(t / "g.txt", b"0 one\n")], ["g.txt"]),
    "edge list empty": (lambda t: ["paper-example-1", "--graph", _write(t / "g.txt", b"")], ["g.txt"]),
    "edge list self-loop": (
        lambda t: ["paper-example-1", "--graph", _write(t / "g.txt", b"0 0\n0 1\n")],
        ["g.txt", "to itself"],
    ),
    "csv with a mark, header only": (
        lambda t: ["--data", _write(t / "d.csv", "\ufeffseed,step,agent,phi_0,next_phi_0,reward\n".encode())],
        ["holds no rows"],
    ),
    "csv with a nan reward": (
        lambda t: ["--data", _write(t / "d.csv", b"seed,step,agent,phi_0,next_phi_0,reward\n" + NAN_ROWS)],
        ["reward"],
    ),
    "loss above 1": (lambda t: ["paper-example-1", "--loss", "1.5"], ["loss"]),
    "loss nan": (lambda t: ["paper-example-1", "--loss", "nan"], ["loss"]),
    "bits 0": (lambda t: ["paper-example-1", "--bits", "0"], ["bits"]),
    "top-k 0": (lambda t: ["paper-example-1", "--top-k", "0"], ["top"]),
    "delay negative": (lambda t: ["paper-example-1", "--delay", "-1"], ["delay"]),
    "wake 0": (lambda t: ["paper-example-1", "--wake", "0"], ["wake"]),
    "alpha0 infinite": (lambda t: ["paper-example-1", "--alpha0", "inf"], ["alpha0"]),
    "alpha0 negative": (lambda t: ["paper-example-1", "--alpha0", "-1"], ["alpha0"]),
    "beta nan": (lambda t: ["paper-example-1", "--beta", "nan"], ["beta"]),
    "seeds 0": (lambda t: ["paper-example-1", "--seeds", "0"], ["seeds"]),
    "edge-prob 0": (lambda t: ["paper-example-1", "--edge-prob", "0"], ["edge"]),
    "out is a file": (lambda t: ["paper-example-1", "--out", _write(t / "f", b"x")], ["f"]),
    "resume nothing": (lambda t: ["--resume", t / "none"], ["none"]),
    "agents with a named task": (lambda t: ["paper-example-1", "--agents", "9"], ["agents"]),
    "features of nan": (
        lambda t: [
            "--env",
            f"{ENVS / 'chain.py'}:make_chain",
            "--features",
            features_file(t, "return np.full((len(states), 2), np.nan)"),
        ],
        ["features"],
    ),
    "features of no columns": (
        lambda t: [
            "--env",
            f"{ENVS / 'chain.py'}:make_chain",
            "--features",
            features_file(t, "return np.ones((len(states), 0))"),
        ],
        ["features"],
    ),
    "features that exit": (
        lambda t: ["--env", f"{ENVS / 'chain.py'}:make_chain", "--features", features_file(t, "raise SystemExit(3)")],
        ["sys.exit(3)"],
    ),
    "unknown toml section": (
        lambda t: [_write(t / "e.toml", b'[problem]\nscenario = "garnet"\n[netwrok]\n')],
        ["netwrok"],
    ),
}


NAN_ROWS = b"0,0,0,1,1,nan\n1,0,0,1,1,0.5\n"  # two recordings, one reward not a number


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


@pytest.mark.parametrize("case", sorted(REFUSED))
def test_a_kept_aside_input_is_one_line_and_exit_2(run_cli, tmp_path, case):
    if "env" in " ".join(map(str, REFUSED[case][0](tmp_path))):
        pytest.importorskip("pettingzoo", reason="the environment extra (pip install dgtd[envs]) is not installed")
    make, words = REFUSED[case]
    args = make(tmp_path)
    out = [] if "--out" in map(str, args) or "--resume" in map(str, args) else ["--out", tmp_path / "o"]
    resumes = "--resume" in map(str, args)
    code, text, err = run_cli("run", *args, *(() if resumes else FAST), *out)
    one_line_error(code, text, err, *words)
    assert not (tmp_path / "o" / "summary.json").exists()


def test_a_process_substitution_is_refused_by_what_it_is(run_cli, tmp_path):
    """`--problem <(cat p.npz)` hands dgtd /dev/fd/N, a pipe: refused as not a regular file, not called missing."""
    read, write = os.pipe()
    try:
        code, text, err = run_cli("run", "--problem", f"/dev/fd/{read}", *FAST, "--out", tmp_path / "o")
    finally:
        os.close(read)
        os.close(write)
    one_line_error(code, text, err, "not a regular file")


def test_a_diverging_run_is_said_to_diverge_with_its_results(run_cli, tmp_path):
    """One bit a number with error feedback on garnet diverges (measured): exit 0, its results written, the table
    saying DIVERGED; never an exit 0 that reads as a success without a word."""
    code, text, err = run_cli(
        "run", "garnet", "--bits", "1", "--error-feedback", "-T", "5000", "--backend", "numpy", "--no-plots",
        "--no-progress", "--out", tmp_path / "o",
    )  # fmt: skip
    assert code == 0, err
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    said = "DIVERGED" in text or "did not converge" in err
    assert said and summary, (text, err)
