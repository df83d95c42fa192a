"""Problem files of the multi-agent MDP form: off-policy problems from the command line, checked like the MRP form."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dgtd.problems import exact
from dgtd.problems.io import load_problem


def chain_arrays(to_first: float = 0.32) -> dict:
    """The two-state chain of tests/algorithms/test_boxes.py as a file: joint actions of agent 0 (2 actions) and
    agent 1 (one), target always to the second state, behaviour to the first with probability ``to_first``; w* = 105
    at 0.32."""
    P = np.zeros((2, 2, 2))
    P[:, 0, 0] = P[:, 1, 1] = 1.0
    return {
        "P": P,
        "R": np.stack([np.full((2, 2), 1.5), np.full((2, 2), 0.5)]),
        "Phi": np.array([[1.0], [2.0]]),
        "gamma": 0.9,
        "policy_0": np.array([[0.0, 1.0], [0.0, 1.0]]),
        "policy_1": np.ones((2, 1)),
        "behaviour_0": np.array([[to_first, 1 - to_first]] * 2),
        "behaviour_1": np.ones((2, 1)),
    }


def write(tmp_path, name="mdp.npz", **arrays):
    path = tmp_path / name
    np.savez(path, **arrays)
    return path


def test_an_mdp_file_is_reduced_exactly_and_runs_off_policy(tmp_path, run_cli):
    path = write(tmp_path, **chain_arrays())
    p = load_problem(path)
    assert p.off_policy and p.n_agents == 2 and exact.w_star(exact.Moments(p)) == pytest.approx([105.0])
    code, out, err = run_cli("solve", "--problem", path, "--graph", "path")
    assert code == 0, err
    solved = json.loads(out)
    assert solved["off_policy"] and solved["w_star"] == pytest.approx([105.0])
    code, out, err = run_cli(
        "run",
        "--problem",
        path,
        "--graph",
        "path",
        "-T",
        "2000",
        "--no-plots",
        "--no-progress",
        "--out",
        tmp_path / "run",
    )
    assert code == 0, err
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["w_star"] == pytest.approx([105.0])


def test_an_episodic_mrp_file_keeps_its_terminal_states(tmp_path):
    from dgtd.problems.io import save_problem
    from dgtd.problems.tasks import boyan

    save_problem(tmp_path / "boyan.npz", boyan(n_agents=3, n_states=13, gamma=1.0))
    p = load_problem(tmp_path / "boyan.npz")
    assert p.terminal.tolist() == [False] * 12 + [True]
    assert exact.w_star(exact.Moments(p)) == pytest.approx([-24.0, -16.0, -8.0, 0.0])


def _without(arrays: dict, *keys) -> dict:
    return {k: v for k, v in arrays.items() if k not in keys}


BAD = {
    "no policies": (
        _without(chain_arrays(), "policy_0", "policy_1", "behaviour_0", "behaviour_1"),
        "no policies: add each agent's local target policy as policy_0",
    ),
    "a gap in the numbering": (_without(chain_arrays(), "policy_0"), "policy_0 is missing"),
    "fewer behaviour policies": (_without(chain_arrays(), "behaviour_1"), "2 target policies but 1 behaviour"),
    "a policy row not summing to 1": ({**chain_arrays(), "policy_0": np.array([[0.5, 0.4], [0.0, 1.0]])}, "policy 0"),
    "a policy of the wrong width": (
        {**chain_arrays(), "policy_1": np.ones((2, 2)) / 2, "behaviour_1": np.ones((2, 2)) / 2},
        "multiply to 4 joint actions but P has 2",
    ),
    "rewards of the wrong shape": ({**chain_arrays(), "R": np.ones((2, 2))}, "rewards must have 3 dimensions"),
    "NaN in P": ({**chain_arrays(), "P": np.full((2, 2, 2), np.nan)}, "NaN"),
    "P(s, a, .) not summing to 1": ({**chain_arrays(), "P": np.full((2, 2, 2), 0.4)}, "P(s, a, .)"),
    "a target action the behaviour never takes": (
        {**chain_arrays(0.32), "behaviour_0": np.array([[1.0, 0.0]] * 2)},
        "never takes joint action 1",
    ),
    "policies with an MRP-form P": (
        {**chain_arrays(), "P": np.full((2, 2), 0.5), "R": np.ones((2, 2))},
        "policies belong to the multi-agent MDP form",
    ),
    "a terminal flag that is not 0 or 1": ({**chain_arrays(), "terminal": np.array([0, 2])}, "terminal must be"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_bad_mdp_file_gets_one_line_and_exit_2(case, tmp_path, run_cli):
    arrays, words = BAD[case]
    code, _, err = run_cli("solve", "--problem", write(tmp_path, **arrays), "--graph", "path")
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("dgtd: error:"), err
    assert words in lines[0], lines[0]


def _mrp_arrays() -> dict:
    """A two-state Markov reward process of two agents in the MRP form."""
    return {
        "P": np.array([[0.3, 0.7], [0.6, 0.4]]),
        "R": np.array([[1.0, 0.0], [0.0, 2.0]]),
        "Phi": np.array([[1.0], [0.5]]),
        "gamma": 0.9,
    }


@pytest.mark.parametrize(
    "name, value, words",
    [
        ("R", np.array([[1.0, 0.0], [0.0, 2.0]]) + 1e-3j, "R in .* holds complex numbers"),
        ("P", np.array([[0.3, 0.7], [0.6, 0.4]], complex), "P in .* holds complex numbers"),
        ("gamma", np.array("0.9"), "gamma in .* holds text"),
        ("Phi", np.array([["1"], ["0.5"]]), "Phi in .* holds text"),
        ("gamma", np.array(True), r"gamma in .* is a boolean \(True\), not a number"),
        ("sigma", np.array(False), r"sigma in .* is a boolean \(False\), not a number"),
    ],
)
def test_a_problem_file_of_numbers_that_are_not_real_is_refused_naming_the_dtype(tmp_path, name, value, words):
    """Complex numbers (their imaginary parts would be dropped), text ("0.9", which float() would read) and a
    boolean discount or reward bound (True read as gamma 1.0, and refused as that) are refused in one line that
    names the array and what it holds, not run."""
    from dgtd.errors import DgtdInputError

    path = write(tmp_path, **{**_mrp_arrays(), name: value})
    with pytest.raises(DgtdInputError, match=words):
        load_problem(path)


def test_probabilities_saved_in_single_precision_are_read_to_their_precision(tmp_path):
    """P and the policies saved as float32 sum to 1 only to float32's precision (1.000000015): read, their rows made
    to sum to 1 in float64, and the problem equal to the float64 one's to that precision; a row off by more than
    float32 can explain is still refused."""
    from dgtd.errors import DgtdInputError

    exact64 = load_problem(write(tmp_path, "a.npz", **_mrp_arrays()))
    P32 = np.array([[0.3, 0.7], [0.1, 0.9]], np.float32)
    assert abs(float(P32.astype(np.float64).sum(1)[1]) - 1.0) > 1e-8  # (float32 cannot hold 0.1 and 0.9 exactly)
    p = load_problem(write(tmp_path, "b.npz", **{**_mrp_arrays(), "P": P32}))
    np.testing.assert_allclose(p.P.sum(1), 1.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(p.P, P32, rtol=1e-7)
    mdp = chain_arrays()
    mdp32 = {k: (v.astype(np.float32) if k.startswith(("P", "policy", "behaviour")) else v) for k, v in mdp.items()}
    w32 = exact.w_star(exact.Moments(load_problem(write(tmp_path, "c.npz", **mdp32))))
    np.testing.assert_allclose(w32, 105.0, rtol=1e-5)  # 0.32 in float32, through the chain's conditioning
    assert exact64.P.dtype == np.float64
    with pytest.raises(DgtdInputError, match="sums to"):
        load_problem(write(tmp_path, "d.npz", **{**_mrp_arrays(), "P": np.array([[0.3, 0.6], [0.1, 0.9]], np.float32)}))


def test_a_misspelt_array_is_refused_by_name_not_ignored(tmp_path, run_cli):
    """`sigam` for `sigma` was ignored, and sigma took its default (changing the boxes and the reward noise)."""
    P = np.array([[0.5, 0.5], [0.5, 0.5]])
    path = write(tmp_path, "mrp.npz", P=P, R=np.ones((2, 2)), Phi=np.eye(2), gamma=0.9, sigam=5.0)
    code, out, err = run_cli("solve", "--problem", path)
    assert code == 2 and "'sigam'" in err and "did you mean 'sigma'" in err and len(err.strip().splitlines()) == 1
    good = write(tmp_path, "mrp2.npz", P=P, R=np.ones((2, 2)), Phi=np.eye(2), gamma=0.9, sigma=5.0)
    assert load_problem(good).sigma == 5.0
    with pytest.raises(Exception, match="policy_0"):
        load_problem(write(tmp_path, "m.npz", **chain_arrays(), policy0=np.ones((2, 1))))
