"""Algorithm 1 written the way research code usually is: Python loops over seeds and agents, NumPy per agent.

Only for the throughput benchmark's speed-up figure; the library never imports it.
"""

from __future__ import annotations

import time

import numpy as np


def per_agent_loop(problem, network, algorithm, seeds: int, iterations: int, d: np.ndarray, seed: int = 0) -> float:
    """Run Algorithm 1 with per-agent Python loops; returns wall seconds (sampling included)."""
    rng = np.random.default_rng(seed)
    N, q, S = problem.n_agents, problem.n_features, problem.n_states
    Phi, P, R, gamma = problem.Phi, problem.P, problem.R, problem.gamma
    edges = [tuple(e) for e in network.base.edges]
    p = network.p
    kappa, rho = algorithm.kappa, algorithm.rho
    box = 1e6
    t0 = time.perf_counter()
    for _ in range(seeds):
        theta = [np.zeros(q) for _ in range(N)]
        v = [np.zeros(q) for _ in range(N)]
        mu = [np.zeros(q) for _ in range(N)]
        w = [np.zeros(q) for _ in range(N)]
        for k in range(iterations):
            alpha = algorithm.alpha0 / np.sqrt(k + algorithm.beta)
            up = [e for e, pe in zip(edges, p) if rng.random() < pe]
            neighbours = [[] for _ in range(N)]
            for i, j in up:
                neighbours[i].append(j)
                neighbours[j].append(i)
            new = []
            for i in range(N):
                s = rng.choice(S, p=d)
                sn = rng.choice(S, p=P[s])
                phi, phin, r = Phi[s], Phi[sn], R[i, s]
                Lw = sum((w[i] - w[j] for j in neighbours[i]), np.zeros(q))
                Lv = sum((v[i] - v[j] for j in neighbours[i]), np.zeros(q))
                Lmu = sum((mu[i] - mu[j] for j in neighbours[i]), np.zeros(q))
                th = theta[i] - alpha * (phi * (phi @ theta[i]) + phi * (phi @ w[i]) - gamma * phi * (phin @ w[i]) - phi * r)
                vv = v[i] - alpha * (v[i] - Lw)
                mm = mu[i] + alpha * (Lw - rho * mu[i])
                ww = w[i] + alpha * ((phi - gamma * phin) * (phi @ theta[i]) - Lv - Lmu - kappa * Lw - rho * w[i])
                new.append(tuple(np.clip(x, -box, box) for x in (th, vv, mm, ww)))
            theta, v, mu, w = (list(x) for x in zip(*new))
    return time.perf_counter() - t0
