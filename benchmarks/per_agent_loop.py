"""Algorithm 1 run the way research code usually runs it: Python loops over seeds, steps and agents, each agent's
neighbour sums formed from Python lists of its links, NumPy per agent.

Each agent's step is the library's reference update (`dgtd.algorithms.DGTD.update`) applied to that agent's own
rows, so Algorithm 1 stays written in one place. Only for the throughput benchmark's speed-up figure; the library
never imports it.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from dgtd.samples import Sample


class _AgentInbox:
    """One agent's neighbour sums sum_j (x_i - x_j), by message name, shaped (1, 1, q) as `update` reads them."""

    def __init__(self, sums: dict):
        self.sums = sums

    def laplacian(self, name: str) -> np.ndarray:
        return self.sums[name]


def per_agent_loop(problem, network, algorithm, seeds: int, iterations: int, d: np.ndarray, seed: int = 0) -> float:
    """Run Algorithm 1 with per-agent Python loops; returns wall seconds (sampling included)."""
    rng = np.random.default_rng(seed)
    N, q, S = problem.n_agents, problem.n_features, problem.n_states
    Phi, P, R, gamma = problem.Phi, problem.P, problem.R, problem.gamma
    edges = [tuple(e) for e in network.base.edges]
    p = network.p
    algorithm = replace(algorithm, boxes=(1e6,) * 4)  # boxes wide enough for any case, narrow enough to stay finite
    t0 = time.perf_counter()
    for _ in range(seeds):
        agents = [algorithm.init(1, 1, q) for _ in range(N)]
        for k in range(iterations):
            alpha = algorithm.alpha0 / np.sqrt(k + algorithm.beta)
            up = [e for e, pe in zip(edges, p) if rng.random() < pe]
            neighbours = [[] for _ in range(N)]
            for i, j in up:
                neighbours[i].append(j)
                neighbours[j].append(i)
            sent = [algorithm.sends(state) for state in agents]
            new = []
            for i in range(N):
                s = rng.choice(S, p=d)
                sn = rng.choice(S, p=P[s])
                sample = Sample(Phi[s][None, None], Phi[sn][None, None], np.array([[R[i, s]]]), np.ones((1, 1)), gamma)
                sums = {
                    name: sum((sent[i][name] - sent[j][name] for j in neighbours[i]), np.zeros((1, 1, q)))
                    for name in algorithm.messages
                }
                new.append(algorithm.update(agents[i], sample, _AgentInbox(sums), alpha))
            agents = new
    return time.perf_counter() - t0
