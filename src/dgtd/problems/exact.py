"""Exact quantities by linear algebra on the model: never by counting samples.

Notation (one agent's block of the paper's stacked matrices; L is the mean Laplacian bold-L, N x N):
    D = diag(d),  M = Phi^T D Phi,  A = Phi^T D (I - gamma P) Phi,  b_i = Phi^T D r_i,

with gamma P the discounted transition matrix gamma(s, s') P(s, s') (`Problem.P_discounted`; gamma P itself in a
continuing task).
Stacked over agents the paper's bar-B is I_N kron A and bar-L is L kron I_q; here agents are the leading
axis of (N, q) arrays, so bar-L x is ``L @ X`` and bar-B x is ``X @ A.T``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.graphs.random import laplacian_pinv
from dgtd.problems.model import Problem, check_size


def stationary_distribution(P: np.ndarray) -> np.ndarray:
    """The unique d with d^T P = d^T, sum d = 1, of an irreducible chain (solved, not estimated)."""
    S = P.shape[0]
    lhs = np.vstack([P.T - np.eye(S), np.ones((1, S))])
    rhs = np.zeros(S + 1)
    rhs[-1] = 1.0
    d, *_ = np.linalg.lstsq(lhs, rhs, rcond=None)
    d = np.clip(d, 0.0, None)
    return d / d.sum()


@dataclass(frozen=True, eq=False)
class Moments:
    """The model's exact moments: d of the behaviour chain and the matrices M, A, b of the MSPBE."""

    problem: Problem
    model = True  # `dgtd.problems.reference.EstimatedMoments` says False: there is no model to solve for d

    def __post_init__(self):
        check_size(self.problem)

    @cached_property
    def d(self) -> np.ndarray:
        """The distribution of the sampled states: the behaviour chain's stationary distribution, conditioned on a
        non-terminal state where an episodic task's restarts are not samples (`Problem.restarts`)."""
        d = stationary_distribution(self.problem.P_behaviour)
        terminal = self.problem.terminal
        if self.problem.restarts == "skipped" and terminal is not None:
            d = np.where(terminal, 0.0, d)
            d /= d.sum()
        return d

    @cached_property
    def M(self) -> np.ndarray:
        Phi = self.problem.Phi
        return Phi.T @ (self.d[:, None] * Phi)

    @cached_property
    def M_factor(self):
        """Cholesky factor of M (symmetric positive definite), computed once: MSPBE evaluations reuse it."""
        from scipy.linalg import cho_factor

        return cho_factor(self.M)

    @cached_property
    def A(self) -> np.ndarray:
        p = self.problem
        return p.Phi.T @ (self.d[:, None] * (p.Phi - p.P_discounted @ p.Phi))

    @cached_property
    def b(self) -> np.ndarray:
        """b_i = Phi^T D r_i for every agent, shape (N, q)."""
        p = self.problem
        return (p.R * self.d) @ p.Phi

    @cached_property
    def b_mean(self) -> np.ndarray:
        return self.b.mean(axis=0)

    @cached_property
    def full_rank(self) -> bool:
        """Whether Phi has full column rank (else M and A are singular: see `w_star`)."""
        return bool(np.linalg.matrix_rank(self.problem.Phi) == self.problem.n_features)

    @cached_property
    def M_inv(self) -> np.ndarray:
        """M^-1 (the pseudo-inverse with dependent features), computed once for every MSPBE evaluation."""
        return np.linalg.inv(self.M) if self.full_rank else np.linalg.pinv(self.M, hermitian=True)

    @cached_property
    def null_projector(self) -> np.ndarray:
        """Orthogonal projector I - Phi^+ Phi onto the null space of Phi (zero when Phi has full column rank)."""
        Phi = self.problem.Phi
        return np.eye(Phi.shape[1]) - np.linalg.pinv(Phi) @ Phi


def _solve(m: Moments, K: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """K^-1 rhs; with dependent features, the least-norm solution (rhs lies in the row space of Phi = range K)."""
    if m.full_rank:
        return np.linalg.solve(K, rhs)
    return np.linalg.lstsq(K, rhs, rcond=None)[0]


def w_star(m: Moments) -> np.ndarray:
    """w* = (Phi^T D (I - gamma P) Phi)^-1 Phi^T D (1/N) sum_i r_i, the solution of Proposition 1."""
    return fixed_point(m, m.b_mean)


def fixed_point(m: Moments, b: np.ndarray) -> np.ndarray:
    """The solution of A w = b (b = Phi^T D r for a reward r; (q,) or (..., q)).

    With dependent features (Phi without full column rank) A w = b has a line of solutions, all with the
    same values Phi w. Every method here moves w along feature vectors, so w - w0 stays in the row space of
    Phi: the solution they reach is (I - P0) A^+ b + P0 w0, P0 the projector onto the null space of Phi and
    w0 the initial weights (zero unless the problem prescribes them).
    """
    b = np.asarray(b, dtype=np.float64)
    if not m.full_rank:
        P0 = m.null_projector
        w0 = np.zeros(P0.shape[0]) if m.problem.w0 is None else m.problem.w0
        sol = np.linalg.lstsq(m.A, b.reshape(-1, b.shape[-1]).T, rcond=None)[0].T
        return (sol @ (np.eye(P0.shape[0]) - P0) + w0 @ P0).reshape(b.shape)
    try:
        return np.linalg.solve(m.A, b.reshape(-1, b.shape[-1]).T).T.reshape(b.shape)
    except np.linalg.LinAlgError:
        raise DgtdInputError(
            "Phi^T D (I - gamma P) Phi is singular; the projected Bellman equation has no unique solution"
        ) from None


def is_symmetric(L) -> bool:
    """Whether a mean mixing Laplacian is exactly symmetric (every link as likely heard both ways)."""
    diff = L - L.T
    return bool(abs(diff).max() == 0) if issparse(L) else bool(np.array_equal(L, L.T))


def agent_weights(L) -> np.ndarray:
    """pi (N,), sum 1: the left null vector of a mean mixing Laplacian (pi^T L = 0, L's rows summing to 0)."""
    L = L.toarray() if issparse(L) else np.asarray(L)
    N = L.shape[0]
    lhs = np.vstack([L.T, np.ones((1, N))])
    rhs = np.concatenate([np.zeros(N), [1.0]])
    return np.linalg.lstsq(lhs, rhs, rcond=None)[0]


def weighted_w_star(m: Moments, L, w: np.ndarray) -> np.ndarray:
    """Where a method that mixes with mean Laplacian L converges: with L symmetric, w* itself (``w``, returned as
    given); else the solution of A w = sum_i pi_i b_i, each agent's reward weighted by the left null vector pi of
    L (`agent_weights`). A mean update that is zero has L w_i summing to consensus and sum_i pi_i (b_i - A w) = 0:
    pi^T L = 0 removes every term the neighbours add (docs/links.md)."""
    if L is None or is_symmetric(L):
        return w
    return fixed_point(m, agent_weights(L) @ m.b)


def directed_saddle_point(m: Moments, L) -> SaddlePoint:
    """The point where DGTD's mean update vanishes when the mean Laplacian L of what is heard is not symmetric (a
    lossy channel): w = `weighted_w_star` for every agent, theta_i = M^-1 (b_i - A w) (the theta equation), v = 0,
    and mu solving L mu = theta A (the w equation), which has a solution because pi^T theta A = 0. Not a saddle
    point of a Lagrangian any more (no Lagrangian has an asymmetric L), but the same four equations at zero."""
    w = weighted_w_star(m, L, w_star(m))
    theta = _solve(m, m.M, (m.b - w @ m.A.T).T).T
    Ld = L.toarray() if issparse(L) else np.asarray(L)
    mu = np.linalg.lstsq(Ld, theta @ m.A, rcond=None)[0]
    return SaddlePoint(theta, np.zeros_like(theta), mu, np.tile(w, (m.b.shape[0], 1)))


def theta_star(m: Moments) -> np.ndarray:
    """theta*_i = M^-1 Phi^T D (r_i - r_mean), shape (N, q).

    From the first of the KKT equations of section 6: M theta_i - b_i + A w* = 0 and A w* = b_mean. The paper's
    appendix (the proof of Proposition 4) has this sign; the statement of Proposition 4 carries the opposite
    sign, which does not satisfy the KKT equations. Tests check the KKT residuals to 1e-9.
    """
    return _solve(m, m.M, (m.b - m.b_mean).T).T


DENSE_N = 2000  # up to this many agents, Laplacian pseudo-inverses are formed densely
REGULARISED_MAX = 1500  # largest N * q whose regularised (rho > 0) saddle point is solved as one dense system


def lap(L, X: np.ndarray) -> np.ndarray:
    """bar-L X along the agent axis (-2) of (..., N, q), for a dense or scipy-sparse L."""
    if not issparse(L):
        return L @ X
    Xm = np.moveaxis(X, -2, 0)
    out = L @ Xm.reshape(Xm.shape[0], -1)
    return np.moveaxis(np.asarray(out).reshape(Xm.shape), 0, -2)


def lap_pinv_apply(L, Y: np.ndarray) -> np.ndarray:
    """L^+ Y for Y (N, q) with columns summing to zero (the range of L).

    Dense: L^+ = (L + 11^T/N)^-1 - 11^T/N of Lemma 2. Sparse: conjugate gradients on
    L + 11^T/N, which equals L^+ Y on such columns (solved to 1e-13 relative residual; a column at a time: all q
    columns at once in NumPy took twice as long, measured at 200 000 agents).
    """
    N = Y.shape[0]
    if not issparse(L) and N <= DENSE_N:
        return laplacian_pinv(L) @ Y
    from scipy.sparse.linalg import LinearOperator, cg

    Ls = L if issparse(L) else csr_from(L)
    op = LinearOperator((N, N), matvec=lambda x: Ls @ x + x.sum() / N, dtype=np.float64)
    out = np.empty_like(Y)
    for j in range(Y.shape[1]):
        x, info = cg(op, Y[:, j], rtol=1e-13, atol=0.0, maxiter=20 * N)
        out[:, j] = x - x.mean()
    return out


def csr_from(L: np.ndarray):
    from scipy.sparse import csr_matrix

    return csr_matrix(L)


def issparse(L) -> bool:
    return hasattr(L, "tocsr")


def mu_star(m: Moments, L) -> np.ndarray:
    """mu* = bar-L^+ bar-B^T theta*, Proposition 5, with L^+ from Lemma 2; shape (N, q). Kept on the moments for
    the Laplacian it was solved with (the saddle point and the boxes' bounds both ask: at a million agents a solve
    takes tens of seconds)."""
    kept = m.__dict__.setdefault("_mu_star", [])
    for L_kept, mu in kept:
        if _same_matrix(L_kept, L):
            return mu
    mu = lap_pinv_apply(L, theta_star(m) @ m.A)
    mu.setflags(write=False)  # shared by every caller
    kept[:] = [(L, mu)]
    return mu


def _same_matrix(K, L) -> bool:
    """Whether two Laplacians (dense or scipy-sparse) hold the same numbers: O(nonzeros), against a solve's
    O(nonzeros x iterations)."""
    if K is L:
        return True
    if K.shape != L.shape or issparse(K) != issparse(L):
        return False
    return bool(abs(K - L).max() == 0) if issparse(K) else bool(np.array_equal(K, L))


@dataclass(frozen=True)
class SaddlePoint:
    """A saddle point of the Lagrangian of section 5 (its form with the consensus term -(kappa/2) w^T L w): arrays
    (N, q)."""

    theta: np.ndarray
    v: np.ndarray
    mu: np.ndarray
    w: np.ndarray


def saddle_point(m: Moments, L, kappa: float = 0.0, rho: float = 0.0) -> SaddlePoint:
    """The saddle point (theta*, v* = 0, mu*, 1 kron w*) of Proposition 4; any kappa >= 0.

    With the regulariser rho > 0 (the modification after Proposition 7) the saddle point moves
    and is unique; it is then found by solving the KKT equations as one linear system (small N q only).
    """
    N = m.b.shape[0]
    if rho == 0.0:
        th = theta_star(m)
        return SaddlePoint(th, np.zeros_like(th), mu_star(m, L), np.tile(w_star(m), (N, 1)))
    q = m.A.shape[0]
    n = N * q
    if n > REGULARISED_MAX:
        raise DgtdInputError(f"the regularised saddle point is solved densely; N*q = {n} is over {REGULARISED_MAX}")
    if issparse(L):
        L = L.toarray()
    I_N, I_q, I_n = np.eye(N), np.eye(q), np.eye(n)
    Lk = np.kron(L, I_q)
    Z = np.zeros((n, n))
    K = np.block(
        [
            [np.kron(I_N, m.M), Z, Z, np.kron(I_N, m.A)],
            [Z, I_n, Z, -Lk],
            [Z, Z, rho * I_n, -Lk],
            [np.kron(I_N, m.A.T), -Lk, -Lk, -(kappa * Lk + rho * I_n)],
        ]
    )
    rhs = np.concatenate([m.b.ravel(), np.zeros(3 * n)])
    x = np.linalg.solve(K, rhs).reshape(4, N, q)
    return SaddlePoint(*x)


def lagrangian_gradient(m: Moments, L, kappa, rho, theta, v, mu, w):
    """Gradient of the Lagrangian of section 5 (with the consensus term -(kappa/2) w^T L w) plus
    (rho/2)|mu|^2 - (rho/2)|w|^2, at stacked (N, q) points.

    Returns (dL/dtheta, dL/dv, dL/dmu, dL/dw); the KKT conditions (section 6) are that all four vanish.
    """
    Lw = lap(L, w)
    g_theta = theta @ m.M - m.b + w @ m.A.T
    g_v = v - Lw
    g_mu = -Lw + rho * mu
    g_w = theta @ m.A - lap(L, v) - lap(L, mu) - kappa * Lw - rho * w
    return g_theta, g_v, g_mu, g_w


def kkt_residuals(m: Moments, L, kappa, rho, point: SaddlePoint) -> dict[str, float]:
    """Max-norm of each KKT equation of section 6 at ``point``."""
    g = lagrangian_gradient(m, L, kappa, rho, point.theta, point.v, point.mu, point.w)
    return {k: float(np.abs(x).max()) for k, x in zip(("theta", "v", "mu", "w"), g, strict=True)}


def mspbe(m: Moments, w: np.ndarray, b: np.ndarray | None = None) -> np.ndarray:
    """MSPBE(w) = 1/2 |Pi(r + gamma P Phi w) - Phi w|_D^2 = 1/2 (b - A w)^T M^-1 (b - A w), the loss of
    GTD in section 2 of the paper.

    ``b`` defaults to the average reward's b_mean; ``w`` may have any leading axes (..., q).
    """
    b = m.b_mean if b is None else b
    # einsum loops in C without BLAS threads, which would contend with the compiled kernels' threads; two
    # operands at a time (a three-operand einsum takes a generic loop, three times slower on 10^4 agents)
    e = b - np.einsum("...j,ij->...i", w, m.A)
    return 0.5 * np.einsum("...j,...j->...", np.einsum("...i,ij->...j", e, m.M_inv), e)


def rmspbe(m: Moments, w: np.ndarray) -> np.ndarray:
    """RMSPBE(w) = |Pi T(Phi w) - Phi w|_D = sqrt(2 MSPBE(w)) (`mspbe` carries the paper's factor 1/2): the root
    projected Bellman error the field reports (e.g. Ghiassian et al. 2020), shape (...)."""
    return np.sqrt(2.0 * np.maximum(mspbe(m, w), 0.0))


def value_error(m: Moments, W: np.ndarray, w_ref: np.ndarray, of: np.ndarray | None = None) -> np.ndarray:
    """The relative value error |Phi w_i - Phi w_ref|_d / |Phi (w_ref - w0)|_d of each agent, shape (..., N).

    The RMSVE of the field (root mean squared value error, Sutton and Barto 2018, section 9.2) weighted by d, the
    stationary distribution of the states the agents sample (the behaviour chain's), relative to the size of the
    reference values: directions of w that barely change the values barely count, unlike in the max-norm weight
    error. It is relative to the value error of the start w0 (zero, Algorithm 1 line 3, unless the task prescribes
    one), which for w0 = 0 is |Phi w_ref|_d, the size of the values; Baird's values are all zero, and its error is
    relative to that of its prescribed start. |Phi x|_d^2 = x^T M x, so no S-sized array is formed. ``w_ref`` (q,)
    or one row per agent (N, q); ``of``: the whole reference whose size scales the error, where ``w_ref`` is some
    agents' rows of it (a rank's; default ``w_ref``).
    """
    diff = W - w_ref
    sq = np.einsum("...j,...j->...", np.einsum("...i,ij->...j", diff, m.M), diff)
    ref = np.atleast_2d(w_ref if of is None else of) - (0.0 if m.problem.w0 is None else m.problem.w0)
    scale = float(np.sqrt(np.einsum("ni,ij,nj->n", ref, m.M, ref).max()))
    return np.sqrt(np.maximum(sq, 0.0)) / max(scale, 1e-300)


def true_value_error(m: Moments, W: np.ndarray) -> np.ndarray:
    """|Phi w_i - J|_d / |J|_d for each agent, shape (..., N): the error to the true value function J of the average
    reward, which the features may not represent (then even w* has a floor, |Phi w* - J|_d / |J|_d)."""
    p = m.problem
    J = value_function(m)
    # (..., N, S), only for the final estimates; each entry summed over the features in one order whatever rows W
    # holds (BLAS gives the rows at a block's edge other bits: a rank's agents would differ from one process's)
    err = np.einsum("...q,sq->...s", W, p.Phi) - J
    return np.sqrt((m.d * err**2).sum(-1)) / max(float(np.sqrt((m.d * J**2).sum())), 1e-300)


def value_function(m: Moments) -> np.ndarray:
    """J^pi of the average reward: J = r_mean + gamma P J (gamma P: `Problem.P_discounted`), solved exactly."""
    p = m.problem
    return np.linalg.solve(np.eye(p.n_states) - p.P_discounted, p.R.mean(axis=0))


def consensus_error(W: np.ndarray) -> np.ndarray:
    """sum_i |w_i - mean_j w_j|_2^2 over the agent axis (-2) of (..., N, q)."""
    return ((W - W.mean(axis=-2, keepdims=True)) ** 2).sum(axis=(-2, -1))


class Pieces(NamedTuple):
    """Nodes of the fixed tree over the agents (`tree_pieces`): node j is the aligned block of agents
    [indices[j] 2^levels[j], (indices[j] + 1) 2^levels[j]), its sum values[j]; arrays, so that ranks exchange them as
    three buffers."""

    levels: np.ndarray  # (k,) int64
    indices: np.ndarray  # (k,) int64
    values: np.ndarray  # (k, B, ...)


def tree_pieces(x: np.ndarray, first: int) -> Pieces:
    """The pieces of the fixed tree over the agents that rows x (B, n, ...) of agents first .. first + n - 1 hold
    whole: the aligned blocks within them (at most two a level), each summed up its own pairwise tree. Any holder of
    the same rows makes the same pieces."""
    levels, indices, values, lo, hi = [], [], [], int(first), int(first) + x.shape[1]
    while lo < hi:
        level = (lo & -lo).bit_length() - 1 if lo else (hi - lo).bit_length() - 1
        while lo + (1 << level) > hi:
            level -= 1
        block = x[:, lo - first : lo - first + (1 << level)]
        while block.shape[1] > 1:  # pairwise up the block's own tree
            block = block[:, 0::2] + block[:, 1::2]
        levels.append(level)
        indices.append(lo >> level)
        values.append(block[:, 0])
        lo += 1 << level
    shape = x.shape[:1] + x.shape[2:]
    return Pieces(
        np.array(levels, np.int64), np.array(indices, np.int64), np.stack(values) if values else np.zeros((0, *shape))
    )


def joined(parts: list[Pieces]) -> Pieces:
    """The pieces of several holders as one."""
    return Pieces(*(np.concatenate([getattr(p, f) for p in parts]) for f in Pieces._fields))


def tree_total(pieces: Pieces, n_agents: int, shape: tuple) -> np.ndarray:
    """The sum (``shape``) of every agent's rows from the pieces (`tree_pieces`) of every holder: combined up the
    fixed tree over agents 0 .. N - 1 (padded to a power of two with nothing: a node missing its right half is its
    left one), so that the total does not depend on who held what. A level at a time over arrays: O(pieces) work
    (1 024 ranks' 17 000 pieces: 4 ms, where a dictionary of nodes took 34)."""
    top = max(1, int(n_agents) - 1).bit_length()
    index, value = np.zeros(0, np.int64), np.zeros((0, *shape))
    for level in range(top + 1):
        at = pieces.levels == level
        index, value = np.concatenate([index, pieces.indices[at]]), np.concatenate([value, pieces.values[at]])
        if level == top:
            break
        if not len(index):  # nothing at this level yet: every piece is a larger block
            continue
        order = np.argsort(index, kind="stable")
        index, value = index[order], value[order]
        parent = index // 2
        first = np.flatnonzero(np.r_[True, parent[1:] != parent[:-1]])  # each parent's first child
        pair = np.r_[first[1:], len(index)] - first == 2  # both halves present: left + right
        combined = value[first].copy()
        combined[pair] = value[first[pair]] + value[first[pair] + 1]
        index, value = parent[first], combined
    return value[0] if len(value) else np.zeros(shape)


def tree_sum(x: np.ndarray) -> np.ndarray:
    """x (B, N, ...) summed over the agents' fixed tree (`tree_pieces`, `tree_total`): the consensus metric's sums,
    the same bit for bit however the agents are spread over ranks (each rank its pieces, one exchange of O(log N)
    of them)."""
    return tree_total(tree_pieces(x, 0), x.shape[1], x.shape[:1] + x.shape[2:])


def ordered_consensus_error(W: np.ndarray, n_agents: int, agents_sum=tree_sum) -> np.ndarray:
    """`consensus_error` of ``n_agents`` agents' rows W (B, n, q), each sum over the agents taken by ``agents_sum``
    (B, n, ...) -> (B, ...): up the agents' fixed tree (this one's: W every agent's), or the ranks'
    (`dgtd.backends.mpi.Ranks.tree_sum`), where W is a rank's rows. The run loop's consensus metric, the same bit for
    bit however the agents are spread."""
    mean = agents_sum(W) / n_agents
    return agents_sum(((W - mean[:, None]) ** 2).sum(axis=-1))


def relative_error(W: np.ndarray, w_ref: np.ndarray, of: np.ndarray | None = None) -> np.ndarray:
    """|w_i - w*|_inf / |w*|_inf for each agent, shape (..., N); ``of``: the whole reference whose size scales the
    error, where ``w_ref`` is some agents' rows of it (default ``w_ref``)."""
    scale = max(float(np.abs(w_ref if of is None else of).max()), 1e-300)
    return np.abs(W - w_ref).max(axis=-1) / scale


@dataclass(frozen=True)
class Bounds:
    """Half-widths of the projection boxes C_theta, C_v, C_mu, C_w (max-norm balls)."""

    theta: float
    v: float
    mu: float
    w: float


def lemma_bounds(m: Moments, L, max_degree: int) -> Bounds:
    """The bounds c of Lemma 2 (its alpha is the discount gamma, as in Bertsekas' Prop. 6.10).

    c_v is free in the lemma (v* = 0); we take 2 * max_degree * c_w, the largest |L(k) w|_inf over boxes.
    c_mu needs |L^+|_inf, which takes the dense pseudo-inverse (O(N^3)): above DENSE_N agents c_mu is instead
    the exact |mu*|_inf (mu* by conjugate gradients), which the lemma's bound only over-estimates.
    """
    p = m.problem
    S, N = p.n_states, p.n_agents
    xi = float(m.d[m.d > 0].min())  # (a terminal state that is never sampled has d = 0 and no say)
    eig = np.linalg.eigvalsh(p.Phi.T @ p.Phi)
    lam = float(eig.min() if m.full_rank else eig[eig > 1e-10 * eig.max()].min())  # dependent features: row space
    J = value_function(m)
    PiJ = p.Phi @ _solve(m, m.M, p.Phi.T @ (m.d * J))
    proj_err = float(np.sqrt(np.sum(m.d * (PiJ - J) ** 2)))
    # gamma = 1 (an episodic task) has no bound of this form: the box is then set by the saddle point alone
    c_w = np.sqrt(S / lam) * (proj_err / np.sqrt(xi) + p.sigma) / (1.0 - p.gamma) if p.gamma < 1.0 else np.inf
    if not m.full_rank:  # plus the part of w* along the null space of Phi, set by w0 (see `w_star`)
        c_w += float(np.abs(m.null_projector @ w_star(m)).max())
    c_theta = 2.0 * p.sigma * S * np.sqrt(N / (xi * lam))
    phi_inf = float(np.abs(p.Phi).sum(axis=1).max())
    if N > DENSE_N:
        c_mu = float(np.abs(mu_star(m, L)).max())
    else:
        Ld = L.toarray() if issparse(L) else L
        L_pinv_inf = float(np.abs(laplacian_pinv(Ld)).sum(axis=1).max()) if N > 1 else 0.0
        c_mu = L_pinv_inf * phi_inf**2 * 2.0 * p.sigma * S**2 * np.sqrt(N / (xi * lam))
    c_v = 2.0 * max_degree * c_w
    return Bounds(float(c_theta), float(c_v), float(c_mu), float(c_w))


def dgtd_mean_dynamics(m: Moments, lam: float, kappa: float, rho: float = 0.0) -> np.ndarray:
    """G(lambda): DGTD's mean update along an eigenvector of the mean Laplacian of eigenvalue ``lam`` is -alpha G
    (theta, v, mu, w) + const (Algorithm 1's lines 7-8 in expectation, `dgtd.algorithms.dgtd.gradient`):
    [[M, 0, 0, A], [0, I, 0, -lam I], [0, 0, rho I, -lam I], [-A^T, lam I, lam I, (kappa lam + rho) I]]."""
    A, M = m.A, m.M
    q = A.shape[0]
    eye, zero = np.eye(q), np.zeros((q, q))
    return np.block(
        [
            [M, zero, zero, A],
            [zero, eye, zero, -lam * eye],
            [zero, zero, rho * eye, -lam * eye],
            [-A.T, lam * eye, lam * eye, (kappa * lam + rho) * eye],
        ]
    )
