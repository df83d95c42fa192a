"""Problem files (.npz), in one of two forms, told apart by the shape of P:

- a Markov reward process: P (S, S), R (N, S), Phi (S, q) and a scalar gamma;
- a multi-agent MDP: the joint P (S, A, S) over joint actions a = (a_1, ..., a_K) flattened in C order, per-agent
  rewards R (N, S, A) or (N, S, A, S), Phi (S, q), gamma, the local target policies policy_0 ... policy_{K-1},
  each (S, A_k), and optionally the local behaviour policies behaviour_0 ... behaviour_{K-1} (off-policy
  evaluation; same shapes). It is reduced exactly by `dgtd.problems.mdp.from_mdp`.

Both may hold a scalar sigma (the reward bound), terminal (S,), 1 at an episodic task's terminal states, and
signed_rewards = 1 to allow negative mean rewards (as the Boyan chain's -3 per step; the paper's lie in [0, sigma]).
"""

from __future__ import annotations

import difflib
import hashlib
from pathlib import Path

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.files import read_npz
from dgtd.problems.model import Problem, make_problem

REQUIRED = ("P", "R", "Phi", "gamma")
FORMS = (
    "give an .npz saved with numpy.savez that holds arrays P (S, S), R (N, S), Phi (S, q) and a scalar gamma, "
    "or for a multi-agent MDP P (S, A, S), R (N, S, A), Phi, gamma and policies policy_0, policy_1, ..."
)


def load_problem(path: str, reward_noise: str = "none", policies: list | None = None) -> Problem:
    """Load and validate a problem file of either form; every failure is a one-line `DgtdInputError`. ``policies``
    (each (S, A_k)) replace a multi-agent MDP file's policy_k (`learned_policies`: a learning run's)."""
    p = Path(path)
    arrays = read_npz(p, "problem file", FORMS, required=REQUIRED)
    _refuse_unknown(path, arrays)
    if policies is not None:
        arrays = _with_policies(path, arrays, policies)
    arrays = {name: _real(path, name, x) for name, x in arrays.items()}
    for k in ("gamma", "sigma", "signed_rewards"):
        if k in arrays and np.asarray(arrays[k]).size != 1:
            raise DgtdInputError(f"{k} in {path} must be a scalar, got shape {np.asarray(arrays[k]).shape}")
    for k in ("gamma", "sigma"):  # a flag read as 1.0 or 0.0 would be refused (or run) as that number
        if k in arrays and np.asarray(arrays[k]).dtype.kind == "b":
            raise DgtdInputError(f"{k} in {path} is a boolean ({np.asarray(arrays[k]).item()}), not a number")
    sigma = float(arrays["sigma"]) if "sigma" in arrays else None
    try:
        gamma = float(np.asarray(arrays["gamma"]).reshape(()))
    except (TypeError, ValueError):
        raise DgtdInputError(f"gamma in {path} must be a number") from None
    terminal = arrays.get("terminal")
    signed = bool(np.asarray(arrays.get("signed_rewards", 0)).reshape(()))
    if np.ndim(arrays["P"]) == 3:
        return _load_mdp(p, arrays, gamma, sigma, reward_noise, terminal, signed)
    stray = sorted(k for k in arrays if k.startswith(("policy_", "behaviour_")))
    if stray:
        raise DgtdInputError(
            f"{path} holds {', '.join(stray)} but P has shape {np.shape(arrays['P'])}; policies belong "
            "to the multi-agent MDP form, whose P is (S, A, S)"
        )
    return make_problem(
        arrays["P"],
        arrays["R"],
        arrays["Phi"],
        gamma,
        sigma=sigma,
        reward_noise=reward_noise,
        name=p.stem,
        terminal=terminal,
        signed_rewards=signed,
    )


KNOWN = ("P", "R", "Phi", "gamma", "sigma", "terminal", "signed_rewards")  # besides policy_k and behaviour_k


def _refuse_unknown(path, arrays: dict) -> None:
    """One line naming an array the file holds that neither form reads (a misspelt ``sigam`` would otherwise be
    ignored, and sigma take its default), with the closest known name."""
    for name in sorted(arrays):
        prefix, _, k = name.rpartition("_")
        if name in KNOWN or (prefix in ("policy", "behaviour") and k.isdigit()):
            continue
        close = difflib.get_close_matches(name, [*KNOWN, "policy_0", "behaviour_0"], n=1, cutoff=0.5)
        raise DgtdInputError(
            f"{path} holds an array {name!r} that a problem file does not have"
            + (f"; did you mean {close[0]!r}?" if close else "")
            + f" (its arrays: {', '.join(KNOWN)}, policy_0, ..., behaviour_0, ...)"
        )


STOCHASTIC = ("P", "policy_", "behaviour_")  # arrays whose last axis holds probabilities that sum to one


def _real(path, name: str, x: np.ndarray) -> np.ndarray:
    """``x`` if it holds real numbers, else one line naming what it holds (complex numbers would lose their imaginary
    parts, text would be read as numbers). Probabilities saved in a lower precision than float64 (float32: rows sum
    to 1.000000015) have their rows divided by their sums in float64 where these are 1 to that precision, so that
    they pass the float64 check; rows further off are left to it, which refuses them."""
    kind = x.dtype.kind
    if kind == "c":
        raise DgtdInputError(
            f"{name} in {path} holds complex numbers ({x.dtype}); a problem's numbers are real: save the real part "
            "(numpy.real) if that is what is meant"
        )
    if kind not in "biuf":
        what = "text" if kind in "US" else f"{x.dtype} values"
        raise DgtdInputError(f"{name} in {path} holds {what}, not numbers; save it as a numeric array")
    if kind == "f" and x.dtype.itemsize < 8 and name.startswith(STOCHASTIC) and x.ndim >= 1 and x.shape[-1]:
        wide = x.astype(np.float64)
        sums = wide.sum(axis=-1, keepdims=True)
        if np.all(np.abs(sums - 1.0) <= 4 * x.shape[-1] * np.finfo(x.dtype).eps) and np.all(wide >= 0):
            return wide / sums
    return x


def _numbered(arrays: dict, prefix: str) -> list:
    """arrays prefix_0, prefix_1, ... in order; a gap in the numbering is an error."""
    found = sorted(int(k[len(prefix) :]) for k in arrays if k.startswith(prefix) and k[len(prefix) :].isdigit())
    if found != list(range(len(found))):
        missing = min(set(range(max(found) + 1)) - set(found))
        raise DgtdInputError(f"{prefix}{missing} is missing: number the arrays {prefix}0, {prefix}1, ... without gaps")
    return [arrays[f"{prefix}{k}"] for k in found]


def _load_mdp(path: Path, arrays: dict, gamma: float, sigma, reward_noise: str, terminal, signed: bool) -> Problem:
    """The multi-agent MDP form, reduced exactly (`from_mdp`)."""
    from dgtd.problems.mdp import from_mdp

    policies = _numbered(arrays, "policy_")
    if not policies:
        raise DgtdInputError(
            f"{path} holds a joint P (S, A, S) but no policies: add each agent's local target policy "
            "as policy_0, policy_1, ... (arrays (S, A_k) whose rows sum to 1)"
        )
    behaviour = _numbered(arrays, "behaviour_") or None
    if behaviour is not None and len(behaviour) != len(policies):
        raise DgtdInputError(
            f"{path} holds {len(policies)} target policies but {len(behaviour)} behaviour policies; "
            "give one behaviour policy per target policy, or none (on-policy)"
        )
    return from_mdp(
        arrays["P"],
        arrays["R"],
        arrays["Phi"],
        gamma,
        policies,
        behaviour,
        sigma=sigma,
        reward_noise=reward_noise,
        name=path.stem,
        terminal=terminal,
        signed_rewards=signed,
    )


def _with_policies(path, arrays: dict, policies: list) -> dict:
    """The file's arrays with ``policies`` in place of its policy_k: as many, each of its shape."""
    own = _numbered(arrays, "policy_")
    if np.ndim(arrays["P"]) != 3 or len(own) != len(policies):
        raise DgtdInputError(
            f"the policies given are {len(policies)} agents'; {path} "
            + (f"holds {len(own)} (policy_0, ...)" if np.ndim(arrays["P"]) == 3 else "is no multi-agent MDP file")
            + ": a learning run's policies replace those of the multi-agent MDP file it learnt on"
        )
    for i, (mine, given) in enumerate(zip(own, policies)):
        if np.shape(mine) != np.shape(given):
            raise DgtdInputError(
                f"agent {i}'s policy given has shape {np.shape(given)}, {path}'s policy_{i} {np.shape(mine)}: the "
                "learning run was of another problem"
            )
    return {k: v for k, v in arrays.items() if not k.startswith("policy_")} | {
        f"policy_{i}": np.asarray(p, np.float64) for i, p in enumerate(policies)
    }


def learned_policies(path: str, seed: int = 0) -> list:
    """The policies a learning run ended with (its folder, or that folder's policies.npz): seed ``seed``'s, each
    agent's (S, A_i) (`dgtd learn` writes policies (seeds, N, S, A_max) and actions (N,))."""
    p = Path(path)
    p = p / "policies.npz" if p.is_dir() else p
    fix = "give a folder dgtd learn wrote (its policies.npz), or that file"
    arrays = read_npz(p, "learning run's policies", fix, required=("policies", "actions"))
    pi, actions = np.asarray(arrays["policies"], np.float64), np.asarray(arrays["actions"])
    if pi.ndim != 4 or actions.shape != (pi.shape[1],):
        raise DgtdInputError(
            f"{p}: policies must be (seeds, N, S, A) and actions (N,); got {pi.shape}, {actions.shape}"
        )
    if not 0 <= seed < pi.shape[0]:
        raise DgtdInputError(f"{p} holds the policies of seeds 0 to {pi.shape[0] - 1}, not of seed {seed}")
    return [pi[seed, i, :, : int(n)] for i, n in enumerate(actions)]


def save_problem(path: str, problem: Problem) -> None:
    """Write a problem's Markov reward process form (P, R, Phi, gamma, sigma) as .npz."""
    extra: dict = {}
    if problem.terminal is not None:
        extra["terminal"] = problem.terminal.astype(np.int64)
    if min(problem.R.min(), problem.R_sample.min()) < 0:
        extra["signed_rewards"] = 1
    np.savez(path, P=problem.P, R=problem.R, Phi=problem.Phi, gamma=problem.gamma, sigma=problem.sigma, **extra)


def file_digest(path: str) -> str:
    """The SHA-256 of a file, read in pieces (a recording may be larger than memory)."""
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def load_team_mdp(path: str):
    """A multi-agent MDP file (the second form above) as a team MDP whose agents learn their policies
    (`dgtd.problems.team.TeamMDP`): one policy per agent (policy_0 ... policy_{N-1}, the starting policies), R
    (N, S, A) or (N, S, A, S) (averaged over s'), no behaviour policies (the actors learn on-policy) and no terminal
    states. Checked as `load_problem` checks a problem file, each failure one line."""
    from dgtd.problems.team import team_mdp

    p = Path(path)
    arrays = read_npz(p, "problem file", FORMS, required=REQUIRED)
    _refuse_unknown(path, arrays)
    arrays = {name: _real(path, name, x) for name, x in arrays.items()}
    if np.ndim(arrays["P"]) != 3:
        raise DgtdInputError(f"{path}: agents that learn need the multi-agent MDP form, P (S, A, S) over joint actions")
    for k in ("behaviour_0", "terminal"):
        if k in arrays:
            raise DgtdInputError(f"{path} holds {k}: learners act on-policy in a continuing task; remove it")
    policies = _numbered(arrays, "policy_")
    R = np.asarray(arrays["R"], dtype=np.float64)
    if R.ndim == 4:
        S = np.shape(arrays["P"])[0]
        if R.shape[1:] != np.shape(arrays["P"]):
            raise DgtdInputError(f"R in {path} has shape {R.shape}; R over next states is (N, S, A, S), S = {S}")
        R = np.einsum("sat,nsat->nsa", arrays["P"], R)
    if len(policies) != R.shape[0]:
        raise DgtdInputError(
            f"{path} holds {len(policies)} policies for {R.shape[0]} agents' rewards: give every agent its starting "
            "policy (policy_0, policy_1, ..., one per row of R)"
        )
    try:
        gamma = float(np.asarray(arrays["gamma"]).reshape(()))
    except (TypeError, ValueError):
        raise DgtdInputError(f"gamma in {path} must be a number") from None
    for i, x in enumerate(policies):
        if np.ndim(x) != 2:
            raise DgtdInputError(
                f"policy_{i} in {path} has shape {np.shape(x)}: a policy is (S, A_{i}), a row of action probabilities "
                f"for each of the {np.shape(arrays['P'])[0]} states"
            )
    actions = [np.shape(x)[1] for x in policies]
    return team_mdp(arrays["P"], R, arrays["Phi"], gamma, actions, name=p.stem, policies=policies)
