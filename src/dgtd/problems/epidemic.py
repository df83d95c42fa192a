"""An epidemic on a network (susceptible-infected-susceptible), as a networked MDP (`dgtd.problems.networked`): each
agent is susceptible (state 0) or infected (1), and each step it waits (action 0) or treats itself (1) at a cost.

    infected:    recovers with probability ``recover`` (``treated`` when it treats);
    susceptible: is infected with probability 1 - (1 - ``spread``)^m, m its infected neighbours, times 1 -
                 ``protection`` when it treats;
    reward       r_i(s_i, a_i) = -1 while infected, - ``cost`` when it treats.

Its next state reads its neighbours' states and its own action only, so the model is exactly a `NetworkedMDP`
(P_i(s_i' | s_N_i, a_i), r_i(s_i, a_i)): exact answers on a few agents (`NetworkedMDP.joint`), and every step keyed by
agent. The heuristics beside the learners (`heuristics`): never treat, always treat, and treat while infected."""

from __future__ import annotations

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.problems.networked import NetworkedMDP, neighbourhoods_of


def epidemic(edges, n_agents: int, spread: float = 0.3, recover: float = 0.1, treated: float = 0.6,
             protection: float = 0.5, cost: float = 0.3, gamma: float = 0.7,
             infected: float = 0.3) -> NetworkedMDP:  # fmt: skip
    """The SIS epidemic of the module's docstring on the graph ``edges`` (E, 2) of ``n_agents``; each agent
    infected at the start with probability ``infected``."""
    rates = dict(spread=spread, recover=recover, treated=treated, protection=protection, infected=infected)
    if not all(0.0 <= v <= 1.0 for v in rates.values()) or not (np.isfinite(cost) and cost >= 0):
        raise DgtdInputError(f"an epidemic's probabilities are in [0, 1] and its cost >= 0; got {rates}, cost {cost}")
    hoods = neighbourhoods_of(edges, n_agents)
    K = hoods.shape[1]
    rows = np.arange(2**K)
    P = np.full((n_agents, 2**K, 2, 2), 0.5)  # (rows beyond an agent's neighbourhood: unused)
    for m in np.unique((hoods >= 0).sum(axis=1)):
        bits = (rows[: 2**m, None] >> np.arange(m - 1, -1, -1)[None, :]) & 1  # (2^m, m): the agent first
        own, sick = bits[:, 0], bits[:, 1:].sum(axis=1)
        catch = 1.0 - (1.0 - spread) ** sick  # (2^m,)
        to_sick = np.stack(
            [
                np.where(own == 1, 1 - recover, catch),  # waits
                np.where(own == 1, 1 - treated, catch * (1 - protection)),
            ],
            axis=1,
        )  # treats; fmt: skip
        agents = np.flatnonzero((hoods >= 0).sum(axis=1) == m)
        P[agents[:, None], rows[None, : 2**m]] = np.stack([1 - to_sick, to_sick], axis=-1)[None]
    R = np.broadcast_to(np.array([[0.0, -cost], [-1.0, -1.0 - cost]]), (n_agents, 2, 2)).copy()
    start = np.array([1 - infected, infected])
    return NetworkedMDP(hoods, P, R, gamma, start, "epidemic")


def heuristics(mdp: NetworkedMDP) -> dict:
    """{name: local policies (N, 2^K, 2)}: never treat, always treat, treat while infected (its own state, the most
    significant digit of its neighbourhood's row)."""
    N, K = mdp.neighbourhoods.shape
    rows = np.arange(2**K)[None, :]
    own = (rows >> np.maximum(mdp.sizes - 1, 0)[:, None]) & 1  # (N, 2^K): its own state in each row
    treat = np.stack([1.0 - own, own.astype(np.float64)], axis=-1)
    never = np.broadcast_to(np.array([1.0, 0.0]), (N, 2**K, 2))
    return {"never treat": never, "always treat": never[..., ::-1], "treat while infected": treat}
