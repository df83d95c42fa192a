"""A reference without a model: the moments of the TD fixed point estimated from samples (LSTD), with their error.

Where there is no model (a simulator, recorded data), w* is the solution of A w = b with the moments
M = E[phi phi^T], A = E[ratio phi (phi - gamma(s, s') phi')^T], b_i = E[ratio phi r_i] under the sampling
distribution: the same fixed point every linear TD method converges to on those samples. LSTD (Bradtke and Barto
1996; Boyan 2002) estimates them by sample means over a large batch of transitions independent of the run's, and
solves (A + lambda I) w = b_mean with a small ridge lambda (`RIDGE`, relative to the scale of A) that keeps the
solve defined where a feature is rarely seen. Its precision is measured, not assumed: the batch comes in G
independent groups (separate simulator copies or episodes), w* is solved on each, and the standard error of w* is
their standard deviation / sqrt(G).

A second check, as the robot example's reference has: a centralised linear TD(0) run (`TDCheck`) on the batch's
transitions (the first 200,000), Polyak-averaged, whose distance to the LSTD w* is reported beside the standard error; a
large gap says the batch is too short for the features, or the features too ill-conditioned, to trust either.

`EstimatedProblem` stands where a `dgtd.problems.model.Problem` would for the run loop: its `moments` answer what
`dgtd.problems.exact` asks of `Moments` (M, A, b), so w*, theta*, mu*, the value error and the MSPBE are computed
from the estimates; what needs the model itself (d, the true value function, Lemma 2's bounds) is absent.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from dgtd.errors import DgtdInputError

KEPT = 2_500  # transitions kept of each group beside its sums (20 000 over the 8 groups of a reference)
RIDGE = 1e-6  # lambda = RIDGE x the largest |diagonal entry| of A: negligible unless a feature is barely seen


@dataclass
class MomentSums:
    """Running sums of the LSTD moments over transitions: call `add` with batches, read `moments` at the end."""

    n_agents: int
    n_features: int
    count: int = 0
    M: np.ndarray = field(init=False)
    A: np.ndarray = field(init=False)
    b: np.ndarray = field(init=False)

    kept: list = field(init=False)  # [(phi, phi', discount, ratio)]: the first `KEPT` transitions added

    def __post_init__(self):
        q, N = self.n_features, self.n_agents
        self.M, self.A, self.b = np.zeros((q, q)), np.zeros((q, q)), np.zeros((N, q))
        self.kept = []

    def add(
        self,
        phi: np.ndarray,
        phi_next: np.ndarray,
        r: np.ndarray,
        discount: np.ndarray,
        ratio: np.ndarray | None = None,
    ) -> None:
        """K transitions: features phi, phi' (K, q), rewards r (K, N), discounts gamma(s, s') (K,), ratios (K,)."""
        phi, phi_next = np.asarray(phi, np.float64), np.asarray(phi_next, np.float64)
        if not (np.isfinite(phi).all() and np.isfinite(phi_next).all() and np.isfinite(r).all()):
            raise DgtdInputError(
                "a transition has NaN or infinite features or rewards; check the states and the features"
            )
        rho = np.ones(len(phi)) if ratio is None else np.asarray(ratio, np.float64)
        room = KEPT - sum(len(x[0]) for x in self.kept)
        if room > 0:
            take = slice(0, room)
            gamma = np.broadcast_to(np.asarray(discount, np.float64), (len(phi),))
            self.kept.append((phi[take].copy(), phi_next[take].copy(), gamma[take].copy(), rho[take].copy()))
        self.M += phi.T @ phi
        self.A += (phi * rho[:, None]).T @ (phi - np.asarray(discount)[:, None] * phi_next)
        self.b += ((phi * rho[:, None]).T @ np.asarray(r, np.float64)).T
        self.count += len(phi)

    def merged(self, other: MomentSums) -> MomentSums:
        both = MomentSums(self.n_agents, self.n_features, self.count + other.count)
        both.M, both.A, both.b = self.M + other.M, self.A + other.A, self.b + other.b
        both.kept = self.kept + other.kept
        return both

    def kept_transitions(self) -> tuple[np.ndarray, ...]:
        """(phi, phi' (K, q), discount, ratio (K,)) of the transitions kept (`KEPT` of each group's first): a sample
        of the batch on which each method's mean dynamics are estimated (`dgtd.algorithms.mean_dynamics`)."""
        return tuple(np.concatenate(parts) for parts in zip(*self.kept))


@dataclass
class TDCheck:
    """Centralised linear TD(0) (Sutton 1988) over transitions in the order given:
    w <- w + alpha_k ratio (r + gamma(s, s') phi'^T w - phi^T w) phi, with alpha_k = 0.5 / (m2 (1 + k / 1000)^0.6),
    m2 = E |phi|^2 on the first batch (so a step moves phi^T w by at most about half the TD error), and the Polyak
    average of the iterates as its answer; at most ``limit`` transitions (a check, not the reference)."""

    n_features: int
    limit: int = 200_000
    k: int = 0
    w: np.ndarray = field(init=False)
    w_avg: np.ndarray = field(init=False)
    m2: float = 0.0

    def __post_init__(self):
        self.w, self.w_avg = np.zeros(self.n_features), np.zeros(self.n_features)

    def add(self, phi, phi_next, r, discount, ratio=None) -> None:
        """K transitions: phi, phi' (K, q), the rewards to learn (K,), discounts (K,), ratios (K,)."""
        n = min(len(phi), self.limit - self.k)
        if n <= 0:
            return
        if self.m2 == 0.0:
            self.m2 = max(float((np.asarray(phi[:n]) ** 2).sum(axis=1).mean()), 1e-12)
        rho = np.ones(n) if ratio is None else np.asarray(ratio, np.float64)
        w, avg, k = self.w, self.w_avg, self.k
        for j in range(n):  # sequential by nature; 200,000 transitions take about a second
            x = phi[j]
            delta = r[j] + discount[j] * (phi_next[j] @ w) - x @ w
            w += (0.5 / (self.m2 * (1.0 + k / 1000.0) ** 0.6)) * rho[j] * delta * x
            k += 1
            avg += (w - avg) / k
        self.k = k


@dataclass(frozen=True, eq=False)
class EstimatedMoments:
    """Sample means of the moments (what `dgtd.problems.exact` reads of `Moments`), with the ridge in A."""

    problem: EstimatedProblem
    M: np.ndarray
    A: np.ndarray
    b: np.ndarray
    d = None  # no model: no stationary distribution
    full_rank = True  # the ridge makes A and M invertible
    model = False

    @cached_property
    def b_mean(self) -> np.ndarray:
        return self.b.mean(axis=0)

    @cached_property
    def M_inv(self) -> np.ndarray:
        return np.linalg.pinv(self.M, hermitian=True)

    @cached_property
    def null_projector(self) -> np.ndarray:
        return np.zeros_like(self.M)


def solve_moments(sums: MomentSums, ridge: float = RIDGE) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(M, A + lambda I, b) as means, and lambda."""
    if sums.count == 0:
        raise DgtdInputError("the reference batch holds no transitions; make it longer")
    M, A, b = sums.M / sums.count, sums.A / sums.count, sums.b / sums.count
    lam = ridge * max(float(np.abs(np.diag(A)).max()), 1e-300)
    M = M + lam * np.eye(len(M))  # so that a feature never seen does not make M singular either
    return M, A + lam * np.eye(len(A)), b, lam


@dataclass(frozen=True, eq=False)
class EstimatedProblem:
    """A problem known through samples only (see the module's docstring); duck-types `Problem` for the run loop.

    ``groups`` (G, q): w* solved on each independent group of the reference batch; ``w_star_stderr`` (q,) their
    standard deviation / sqrt(G); ``transitions``: the batch's size; ``ridge``: the lambda used (``ridge_factor``
    x the largest diagonal entry of A).
    """

    name: str
    n_agents: int
    n_features: int
    gamma: float
    sums: MomentSums
    groups: np.ndarray
    ridge_factor: float = RIDGE
    off_policy: bool = False
    w0: np.ndarray | None = None
    description: str = ""
    td_check: TDCheck | None = None
    # What the run loop reads of a Problem and that has no meaning here: every block carries its own rows
    reward_noise: str = "none"
    terminal: np.ndarray | None = None
    state_labels: tuple = ()

    @cached_property
    def moments(self) -> EstimatedMoments:
        M, A, b, _ = solve_moments(self.sums, self.ridge_factor)
        return EstimatedMoments(self, M, A, b)

    @property
    def ridge(self) -> float:
        return solve_moments(self.sums, self.ridge_factor)[3]

    @property
    def transitions(self) -> int:
        return self.sums.count

    @property
    def w_star(self) -> np.ndarray:
        return np.linalg.solve(self.moments.A, self.moments.b_mean)

    @property
    def w_star_stderr(self) -> np.ndarray:
        G = len(self.groups)
        return self.groups.std(axis=0, ddof=1) / np.sqrt(G) if G > 1 else np.full(self.n_features, np.nan)

    @property
    def value_stderr(self) -> float:
        """The standard error of the reference's values, |Phi (w*_hat - w*)|_d, relative to |Phi w*|_d: from the
        spread of the groups' w* in the d-weighted norm, sqrt(sum_g |Phi (w_g - mean)|_d^2 / (G (G - 1)))."""
        G, M = len(self.groups), self.moments.M
        dev = self.groups - self.groups.mean(axis=0)
        spread = float(np.einsum("gi,ij,gj->", dev, M, dev)) / (G * (G - 1)) if G > 1 else float("nan")
        return float(np.sqrt(spread / max(float(self.w_star @ M @ self.w_star), 1e-300)))

    def summary(self) -> dict:
        """What summary.json says of the reference: that it is estimated, from how much, and how precisely."""
        w, se = self.w_star, self.w_star_stderr
        scale = max(float(np.abs(w).max()), 1e-300)
        return {
            "estimated": True,
            "method": "LSTD with a ridge",
            "ridge": self.ridge,
            "transitions": self.transitions,
            "groups": len(self.groups),
            "w_star_stderr": se.tolist(),
            "w_star_stderr_relative": float(np.abs(se).max() / scale),
            "value_stderr_relative": self.value_stderr,
            **(
                {}
                if self.td_check is None
                else {"td_check_transitions": self.td_check.k, "td_check_value_gap": self.td_gap}
            ),
        }

    @property
    def td_gap(self) -> float:
        """|Phi (w_TD - w*)|_d / |Phi w*|_d of the centralised TD(0) check (d: the reference batch's states)."""
        assert self.td_check is not None, "no TD(0) check was run"
        M, dev = self.moments.M, self.td_check.w_avg - self.w_star
        return float(np.sqrt((dev @ M @ dev) / max(float(self.w_star @ M @ self.w_star), 1e-300)))

    # duck-typed Problem fields
    @property
    def Phi(self) -> np.ndarray:
        return np.zeros((1, self.n_features))

    @property
    def ratio(self) -> np.ndarray:
        return np.ones((1, 1))

    @property
    def R(self) -> np.ndarray:
        return np.zeros((self.n_agents, 1))

    @property
    def R_sample(self) -> np.ndarray:
        return np.zeros((self.n_agents, 1, 1))

    @property
    def sigma(self) -> float:
        return 1.0

    @property
    def n_states(self) -> int:
        return 1

    @property
    def continuing(self) -> np.ndarray:
        return np.ones(1)


def estimate(
    name: str,
    gamma: float,
    group_sums: list[MomentSums],
    ridge: float = RIDGE,
    off_policy: bool = False,
    description: str = "",
    td_check: TDCheck | None = None,
) -> EstimatedProblem:
    """The reference from G >= 2 independent groups of transitions' moment sums (and a TD(0) check, if run)."""
    if len(group_sums) < 2:
        raise DgtdInputError("the reference needs at least two independent groups of transitions for its error")
    total = group_sums[0]
    for g in group_sums[1:]:
        total = total.merged(g)
    groups = []
    for g in group_sums:
        _, A, b, _ = solve_moments(g, ridge)
        groups.append(np.linalg.solve(A, b.mean(axis=0)))
    return EstimatedProblem(
        name,
        total.n_agents,
        total.n_features,
        float(gamma),
        total,
        np.array(groups),
        ridge,
        off_policy=off_policy,
        description=description,
        td_check=td_check,
    )
