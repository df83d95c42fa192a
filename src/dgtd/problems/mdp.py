"""Multi-agent MDP form (paper section 'Distributed reinforcement learning overview'), reduced exactly to a `Problem`.

Joint actions a = (a_1, ..., a_N) are flattened in C order over ``action_sizes``. The joint policy is the
product of the local ones, pi(s, a) = prod_i pi_i(s, a_i), and likewise for the behaviour policies; the
importance ratio of a joint action is the product of the local ratios.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.problems.model import Problem, _as_float_array, check_stochastic, make_problem


def joint_policy(local_policies: Sequence[np.ndarray]) -> np.ndarray:
    """pi(s, a) = prod_i pi_i(s, a_i) with a flattened in C order; shape (S, prod_i A_i)."""
    joint = np.ones((local_policies[0].shape[0], 1))
    for pi_i in local_policies:
        joint = (joint[:, :, None] * pi_i[:, None, :]).reshape(joint.shape[0], -1)
    return joint


def from_mdp(
    P,
    rewards,
    Phi,
    gamma: float,
    policies: Sequence,
    behaviour: Sequence | None = None,
    *,
    sigma: float | None = None,
    reward_noise: str = "none",
    name: str = "mdp",
    terminal=None,
    signed_rewards: bool = False,
) -> Problem:
    """Reduce a multi-agent MDP to the Markov reward process form, exactly.

    - ``P`` (S, A, S): P(s, a, s') over flattened joint actions a.
    - ``rewards`` (N, S, A, S) mean reward r_i(s, a, s'), or (N, S, A) when it does not depend on s'.
    - ``policies``: N arrays pi_i (S, A_i), the target local policies; A = prod_i A_i.
    - ``behaviour``: N arrays beta_i (S, A_i) for off-policy evaluation, or None (on-policy).
    - ``terminal`` (S,) flags of an episodic task's terminal states (`dgtd.problems.model.Problem`).

    Returns P^pi(s, s') = sum_a pi(s, a) P(s, a, s') and r_i^pi(s) = sum_{a, s'} pi(s, a) P(s, a, s') r_i(s, a, s'),
    with the behaviour sampling model beta(s, a) P(s, a, s') and ratios pi(s, a) / beta(s, a).
    """
    P = _as_float_array("P", P, 3)
    S, A, S2 = P.shape
    if S2 != S:
        raise DgtdInputError(f"P must have shape (S, A, S), got {P.shape}")
    check_stochastic("P(s, a, .)", P.reshape(S * A, S))
    policies = [_as_float_array(f"policy {i}", p, 2) for i, p in enumerate(policies)]
    for i, p in enumerate(policies):
        if p.shape[0] != S:
            raise DgtdInputError(f"policy {i} must have one row per state ({S}), got shape {p.shape}")
        check_stochastic(f"policy {i}", p)
    pi = joint_policy(policies)
    if pi.shape[1] != A:
        raise DgtdInputError(f"the local policies' action counts multiply to {pi.shape[1]} joint actions but P has {A}")
    R_sa, R_transition = _mean_rewards(rewards, P)
    beta = pi if behaviour is None else _behaviour(behaviour, policies)
    if np.any((pi > 0) & (beta == 0)):
        s, a = np.argwhere((pi > 0) & (beta == 0))[0]
        raise DgtdInputError(
            f"the behaviour policy never takes joint action {a} in state {s} that the target policy takes; "
            "off-policy evaluation needs beta(a|s) > 0 wherever pi(a|s) > 0"
        )
    ratio = np.divide(pi, beta, out=np.zeros_like(pi), where=beta > 0)
    P_pi = np.einsum("sa,sat->st", pi, P)
    R_pi = np.einsum("sa,nsa->ns", pi, R_sa)
    return make_problem(
        P_pi,
        R_pi,
        Phi,
        gamma,
        P_sample=beta[:, :, None] * P,
        ratio=ratio,
        R_sample=R_sa,
        sigma=sigma,
        reward_noise=reward_noise,
        name=name,
        terminal=terminal,
        signed_rewards=signed_rewards,
        R_transition=R_transition,
    )


def _mean_rewards(rewards, P: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """(r_i(s, a) (N, S, A), r_i(s, a, s') (N, S, A, S) where the rewards depend on s', else None), checked."""
    S, A, _ = P.shape
    rewards = np.asarray(rewards, dtype=np.float64)
    if rewards.ndim == 4:
        rewards = _as_float_array("rewards", rewards, 4)
        if rewards.shape[1:] != (S, A, S):
            raise DgtdInputError(f"rewards must have shape (N, {S}, {A}, {S}), got {rewards.shape}")
        return np.einsum("sat,nsat->nsa", P, rewards), rewards
    R_sa = _as_float_array("rewards", rewards, 3)
    if R_sa.shape[1:] != (S, A):
        raise DgtdInputError(f"rewards must have shape (N, {S}, {A}) or (N, {S}, {A}, {S}), got {rewards.shape}")
    return R_sa, None


def _behaviour(behaviour: Sequence, policies: list) -> np.ndarray:
    """The joint behaviour policy beta (S, A) of the agents' local ones, each checked against its target policy."""
    behaviour = [_as_float_array(f"behaviour policy {i}", b, 2) for i, b in enumerate(behaviour)]
    if len(behaviour) != len(policies):
        raise DgtdInputError(
            f"{len(policies)} target policies but {len(behaviour)} behaviour policies; give one "
            "behaviour policy per target policy"
        )
    for i, (b, p) in enumerate(zip(behaviour, policies, strict=True)):
        if b.shape != p.shape:
            raise DgtdInputError(f"behaviour policy {i} has shape {b.shape}, its target policy {p.shape}")
        check_stochastic(f"behaviour policy {i}", b)
    return joint_policy(behaviour)
