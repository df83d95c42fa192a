"""Every algorithm's mean dynamics on a model, from its one definition (`dgtd.algorithms.base`), and the first step
they allow: the rule behind the steps `dgtd run` and `dgtd compare` take from a user's problem file, simulator or
recording.

On a model the expected step of every algorithm here is affine in its state: the directions are linear in the
products phi^T x it reads, and ``feature`` is linear in the state, what it heard and the directions. Along an
eigenvector of the mean mixing matrix (the mean Laplacian E[L(k)], or E[I - W(k)] of Metropolis mixing: what an
agent hears is then ``lam`` times what it sends) the mean step is x <- J(alpha, lam) x + const. `MeanMap` builds
J exactly: the expected directions by summing ``coefficients`` and ``terms`` over every transition (s, a, s') of
the behaviour chain with its probability d(s) beta(a|s) P(s, a, s'), for the unit vectors of every state field, and
``feature`` of those. For DGTD it equals I - alpha G(lam) of Algorithm 1 in expectation
(`dgtd.problems.exact.dgtd_mean_dynamics`, the closed form the tests check it against). Without a model (an
estimated reference) the sum runs over the transitions the reference kept, each of the same weight: an estimate.

`first_step` is then the same rule for every method: half the largest first step at which every mode of the mean
dynamics contracts (|nu| < 1 for every eigenvalue nu of J other than the modes J leaves alone, nu = 1), for every
mixing eigenvalue; and at most the step at which a single sample overshoots along its own features (the largest of
the step sizes it derives from alpha times max ratio(s, a) |phi(s)|^2 at most 1: off-policy, a sample's step is its
importance ratio times on-policy's). For a method whose every mode is
I - alpha nu (DGTD, TD(0), TDRC) half the largest contracting step is min Re(nu) / |nu|^2 over its modes.

Off-policy the mean is not enough: with large importance ratios a step at which the mean contracts can let the
spread about it grow (on Baird's counterexample at 1 / 35 every gradient-TD method's does, and `local` diverged on a
file with ratios 10). There the step is at most half the largest at which the second moment of one agent's update
contracts: the spectral radius of X -> E[J_t X J_t^T] below 1, J_t the update of one sample
(`second_moment_step`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.sparse import coo_matrix

from dgtd.algorithms.stepsizes import step_sizes
from dgtd.samples import Sample, discount

SPREAD = 24  # beyond this many distinct mixing eigenvalues, this many points spread over their range
BISECTIONS = 16  # halvings of the bracket of the largest contracting step, where it has no closed form
LARGEST = 4e9  # mixing eigenvalues x (state size)^3 beyond which the rule is not tried (about 5 s on 2 cores)
LEFT_ALONE = 1e-9  # |nu - 1| below this: a mode the dynamics leave alone (an invariant, as sum z - g of tracking)


def transitions(moments) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, Sample]:
    """(rows (R, q) of features, the row of each transition's s and of its s' (T,), its probability (T,), a `Sample`
    (1, T, 1) of unit features and rewards 0 with its importance ratio and discount gamma(s, s'), which an
    algorithm's coefficients read).

    On a model: every transition (s, a, s') of the behaviour chain with positive probability d(s) beta(a|s)
    P(s, a, s'), the rows its features Phi. Without one (a simulator's or a recording's estimated reference): the
    transitions its reference kept (`dgtd.problems.reference.MomentSums.kept_transitions`), each of weight 1 / T:
    the mean dynamics of that sample, an estimate as its w* is."""
    if not moments.model:
        phi, phi_next, discount, ratio = moments.problem.sums.kept_transitions()
        T = len(phi)
        one = np.ones((1, T, 1))
        sample = Sample(one, one, np.zeros((1, T)), ratio[None], discount[None])
        return np.concatenate([phi, phi_next]), np.arange(T), T + np.arange(T), np.full(T, 1.0 / T), sample
    problem = moments.problem
    weight = moments.d[:, None, None] * problem.P_sample
    s, a, s_next = np.nonzero(weight > 0)
    c = problem.continuing
    gamma = (problem.gamma * c[s] * c[s_next])[None]
    one = np.ones((1, s.size, 1))
    sample = Sample(one, one, np.zeros((1, s.size)), problem.ratio[s, a][None], gamma)
    return problem.Phi, s, s_next, weight[s, a, s_next], sample


def expected_directions(algorithm, known: tuple) -> dict:
    """{(direction, field): K (q, q)}: E[d] = sum over fields of K x_field, exactly.

    Per transition an algorithm's coefficients are linear in the products it ``reads`` (rewards 0) and its
    ``terms`` are a phi(s) + b phi(s') per feature with a, b linear in the coefficients (what the compiled driver
    relies on too); so read k (phi_k^T x_f, phi_k = phi(s) or phi(s')) adds sum over (s, s') of its weight times
    (a phi(s) + b phi(s')) phi_k^T: Phi^T of a (sparse) matrix of weights over pairs of rows times Phi. ``known``:
    the `transitions` of a model or a reference."""
    p = algorithm.params()
    Phi, s, s_next, weight, unit = known
    S = Phi.shape[0]
    zero = np.zeros_like(unit.phi)
    K: dict = {}
    for k, (src, field) in enumerate(algorithm.reads):
        dots = tuple(np.full(unit.r.shape, float(j == k)) for j in range(len(algorithm.reads)))
        c = tuple(np.asarray(v)[..., None] for v in algorithm.coefficients(p, dots, unit.r, unit.ratio, unit.gamma))
        g = discount(unit)
        along_s = algorithm.terms(p, unit.phi, zero, c, g)  # a of each direction (1, T, 1)
        along_next = algorithm.terms(p, zero, unit.phi, c, g)  # b
        read = s if src == "phi" else s_next
        for out, (a, b) in enumerate(zip(along_s, along_next)):
            # W[u, v]: the weight of phi(u) phi(v)^T, v the read's row (sparse: a user's chain may be large)
            at = np.concatenate([s, s_next])
            value = weight * np.concatenate([per_transition(a, s.size), per_transition(b, s.size)]).reshape(2, -1)
            W = coo_matrix((value.ravel(), (at, np.concatenate([read, read]))), shape=(S, S)).tocsr()
            K[out, field] = K.get((out, field), 0.0) + Phi.T @ (W @ Phi)
    return K


def per_transition(x, size: int) -> np.ndarray:
    """A coefficient of every transition, (size,), from what ``terms`` returned (an array (1, T, 1), or a float)."""
    return np.broadcast_to(np.asarray(x, dtype=np.float64), (1, size, 1))[0, :, 0]


class MeanMap:
    """J(alpha, lam) of ``algorithm`` on the `transitions` ``known`` of a model or a reference (the module's
    docstring): the expected directions (`expected_directions`) are summed once; each J is one ``feature`` of them
    over the unit vectors of the state."""

    def __init__(self, algorithm, known: tuple):
        self.algorithm = algorithm
        q = known[0].shape[1]
        self.fields = type(algorithm.init(1, 1, 1))._fields
        n = len(self.fields)
        eye = np.eye(n * q).reshape(n * q, n, q)
        self.probes = tuple(eye[:, f, None, :] for f in range(n))  # (P, 1, q) each: every unit vector
        K = expected_directions(algorithm, known)
        outputs = 1 + max((out for out, _ in K), default=-1)
        x = dict(zip(self.fields, self.probes))
        self.directions = tuple(
            sum((x[f] @ K[out, f].T for (o, f) in K if o == out), np.zeros_like(self.probes[0]))
            for out in range(outputs)
        )

    def __call__(self, alpha: float, lam: float) -> np.ndarray:
        a = self.algorithm
        p = a.params()
        heard = tuple(lam * m for m in a.transmit(self.probes))
        new = a.feature(p, self.probes, heard, self.directions, a.steps(p, alpha))
        return np.concatenate([np.broadcast_to(x, self.probes[0].shape)[:, 0, :] for x in new], axis=1).T


def mixing_eigenvalues(algorithm, network) -> np.ndarray:
    """The eigenvalues of the mean mixing the algorithm applies to what it hears over perfect links: E[L(k)], or the
    Metropolis E[I - W(k)] (`dgtd.channels.perfect.mean_metropolis`); [0] for one that does not communicate. Beyond
    `SPREAD` distinct ones, `SPREAD` points spread over their range and the smallest non-zero one. Up to
    `dgtd.problems.exact.DENSE_N` agents all of them, from the dense matrix; beyond, only those two ends, from the
    sparse one (`dgtd.graphs.random.spectrum_ends`): O(|E|) memory, never N x N."""
    if not algorithm.messages:
        return np.zeros(1)
    key = (algorithm.mixing, _digest_of(network.base.edges, network.p, np.array([network.n_nodes])))
    if key not in _MIXINGS:  # a run asks up to three times (its steps, the growing-mode check, its header)
        if len(_MIXINGS) >= 8:
            _MIXINGS.pop(next(iter(_MIXINGS)))
        _MIXINGS[key] = _mixing_eigenvalues(algorithm.mixing, network)
    return _MIXINGS[key]


_MIXINGS: dict = {}


def _mixing_eigenvalues(kind: str, network) -> np.ndarray:
    from dgtd.problems.exact import DENSE_N

    sparse = network.n_nodes > DENSE_N
    if kind == "metropolis":
        from dgtd.channels.perfect import mean_metropolis

        mixing = mean_metropolis(network, sparse)
    else:
        mixing = network.mean_laplacian(sparse=sparse)
    if sparse:
        from dgtd.graphs.random import spectrum_ends

        largest, smallest, _ = spectrum_ends(mixing)
        lams = np.array([0.0, largest])
    else:
        lams = np.unique(np.round(np.linalg.eigvalsh(mixing), 12))
        if lams.size <= SPREAD:
            return lams
        smallest = lams[lams > 1e-12][0]
    return np.unique(np.concatenate([np.linspace(0.0, lams[-1], SPREAD), [smallest]]))


def contracts(mean_map: MeanMap, alpha: float, lam: float) -> bool:
    """Whether every mode of J(alpha, lam) that moves (`LEFT_ALONE`) contracts."""
    nu = np.linalg.eigvals(mean_map(alpha, lam))
    nu = nu[np.abs(nu - 1.0) > LEFT_ALONE]
    return not nu.size or bool(np.abs(nu).max() < 1.0)


def largest_contracting_step(mean_map: MeanMap, lam: float, hi: float) -> float:
    """The largest alpha up to ``hi`` below which every moving mode of J(alpha, lam) contracts (0: none does).

    Where J(alpha) = c I + alpha J1 (DGTD, TD(0), TDRC, the consensus methods: c = 1 or 1 - lam) it is exact from
    the eigenvalues mu of J1: |c + alpha mu| < 1 up to the larger root of |mu|^2 a^2 + 2 c Re(mu) a + c^2 - 1; else
    (two timescales, tracking) by bisection, assuming the steps that contract form an interval from 0."""
    J0 = mean_map(0.0, lam)
    J1 = mean_map(1.0, lam) - J0
    c = J0[0, 0]
    if np.allclose(J0, c * np.eye(len(J0)), rtol=0, atol=1e-12) and np.allclose(mean_map(2.0, lam), J0 + 2 * J1):
        mu = np.linalg.eigvals(J1)
        if c == 1.0:
            mu = mu[np.abs(mu) > LEFT_ALONE]
        size = np.abs(mu) ** 2
        root = np.where(
            size > 0,
            (-c * mu.real + np.sqrt(np.maximum((c * mu.real) ** 2 - size * (c**2 - 1.0), 0.0)))
            / np.maximum(size, 1e-300),
            np.inf if abs(c) < 1.0 else 0.0,
        )
        return float(min(np.clip(root, 0.0, None).min(initial=np.inf), hi))
    if contracts(mean_map, hi, lam):
        return hi
    lo = 0.0
    if not contracts(mean_map, hi * 2.0**-BISECTIONS, lam):
        return lo
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if contracts(mean_map, mid, lam) else (lo, mid)
    return lo


def sample_cap(algorithm, largest: float) -> float:
    """The largest alpha at which no step size it derives (``steps``) exceeds 1 / ``largest``, max_s |phi(s)|^2."""
    p = algorithm.params()
    lo, hi = 0.0, 1.0 / largest
    while max(algorithm.steps(p, hi)) * largest <= 1.0 and hi < 1e12:  # a slower auxiliary step: a larger alpha
        lo, hi = hi, 2.0 * hi
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if max(algorithm.steps(p, mid)) * largest <= 1.0 else (lo, mid)
    return lo


def first_step(algorithm, moments, network) -> tuple[float | None, str]:
    """(the largest first step alpha_1 the problem suggests, or None where no step contracts; why, in words): the
    rule of the module's docstring. Kept for the same algorithm, model and mixing (`dgtd run` asks when it resolves
    the run and again for its header: on a model of hundreds of features the eigenvalues take seconds)."""
    lams = mixing_eigenvalues(algorithm, network)
    size = len(algorithm.init(1, 1, 1)) * moments.problem.n_features
    if len(lams) * size**3 > LARGEST:
        return None, (
            f"its mean dynamics ({size} x {size}, for each of {len(lams)} mixing eigenvalues) are too large to "
            "analyse at the start of a run"
        )
    known = transitions(moments)
    key = (algorithm, _digest(known, lams))
    if key not in _FIRST_STEPS:
        if len(_FIRST_STEPS) >= 8:
            _FIRST_STEPS.pop(next(iter(_FIRST_STEPS)))
        _FIRST_STEPS[key] = _first_step(algorithm, known, lams)
    return _FIRST_STEPS[key]


_FIRST_STEPS: dict = {}


def _digest(transitions: tuple, lams: np.ndarray) -> str:
    """What the rule reads of a model (or a reference's sample) and its mixing, as one SHA-256."""
    rows, s, s_next, weight, sample = transitions
    return _digest_of(rows, s, s_next, weight, sample.ratio, sample.gamma, lams)


def _digest_of(*arrays) -> str:
    """The arrays' numbers and shapes, as one SHA-256."""
    import hashlib

    h = hashlib.sha256()
    for x in arrays:
        h.update(np.ascontiguousarray(x, dtype=np.float64).tobytes() + str(np.shape(x)).encode())
    return h.hexdigest()


def overshoot(known: tuple) -> float:
    """max ratio |phi(s)|^2 over the transitions (at least max_s |phi(s)|^2): a sample's step along its own features
    is alpha times its importance ratio times |phi(s)|^2, so past 1 / this one sample overshoots."""
    rows, s, _, weight, sample = known
    phi2 = (rows**2).sum(axis=1)
    ratio = np.asarray(sample.ratio).reshape(-1)
    seen = weight > 0
    return float(max(phi2.max(), (ratio[seen] * phi2[s[seen]]).max(initial=0.0)))


def _first_step(algorithm, known: tuple, lams: np.ndarray) -> tuple[float | None, str]:
    largest_phi = overshoot(known)  # max ratio |phi(s)|^2, max_s |phi(s)|^2 on-policy
    cap = sample_cap(algorithm, largest_phi)
    mean_map = MeanMap(algorithm, known)
    largest = min(largest_contracting_step(mean_map, float(lam), 2.0 * cap) for lam in lams)
    if largest <= 0.0:
        return None, "no step makes every mode of its mean dynamics contract here"
    off_policy = known[4].ratio.max() > 1.0
    over, bound = 1.0 / largest_phi, "1 / max ratio |phi(s)|^2" if off_policy else "1 / max |phi(s)|^2"
    if largest >= 2.0 * cap:
        step, why = (
            cap,
            (
                f"its step sizes at most {bound} = {over:.3g}, where one sample overshoots (every mode of its "
                "mean dynamics contracts at twice that)"
            ),
        )
    else:
        step, why = (
            0.5 * largest,
            (f"half the largest at which every mode of its mean dynamics contracts ({bound}: {over:.3g})"),
        )
    if off_policy:
        second = second_moment_step(algorithm, known, 2.0 * step)
        if 0.5 * second < step:
            ratio = float(known[4].ratio.max())
            return 0.5 * second, (
                f"half the largest at which the second moment of one agent's update contracts (importance ratios up "
                f"to {ratio:.3g}: at {step:.3g}, which the mean dynamics allow, the spread about the mean grows)"
            )
    return step, why


SECOND_MOMENT_WORK = 2e10  # transitions x (state size)^3 beyond which the second moment is not analysed (~5 s)
SECOND_MOMENT_KINDS = 2000  # distinct transitions beyond which it is not (a `MeanMap` each, ~2 ms)


def one_transition_maps(algorithm, known: tuple, limit: float = np.inf) -> tuple[list, np.ndarray]:
    """(the `MeanMap` of each distinct transition alone, its probability): J_t(alpha, lam) of one sample, the
    random matrix whose mean is the mean map. Transitions that read the same rows with the same ratio and
    discount are one. ([], []) where there are more than ``limit``."""
    rows, s, s_next, weight, sample = known
    ratio = np.asarray(sample.ratio, dtype=float).reshape(-1)
    gamma = np.broadcast_to(np.asarray(sample.gamma, dtype=float), (1, s.size)).reshape(-1)
    kinds, which = np.unique(np.stack([s, s_next, ratio, gamma], axis=1), axis=0, return_inverse=True)
    if len(kinds) > limit:
        return [], np.zeros(0)
    weights = np.bincount(which.reshape(-1), weights=weight, minlength=len(kinds))
    maps = []
    for u, t, r, g in kinds:
        one = np.ones((1, 1, 1))
        alone = Sample(one, one, np.zeros((1, 1)), np.full((1, 1), r), np.full((1, 1), g))
        maps.append(MeanMap(algorithm, (rows, np.array([int(u)]), np.array([int(t)]), np.ones(1), alone)))
    return maps, weights


def second_moment_radius(J: np.ndarray, weights: np.ndarray) -> float:
    """The spectral radius of X -> E[J_t X J_t^T] = sum_t p_t J_t X J_t^T, ``J`` (T, n, n) one agent's update on
    each of its own samples: below 1 the spread of its iterates about their mean stays bounded; above, it grows
    though the mean contracts. (A completely positive map: its radius is an eigenvalue; ARPACK finds it on the
    matrix form where the n^2 x n^2 matrix would be large.)"""
    from scipy.sparse.linalg import LinearOperator, eigs

    n = J.shape[1]
    if n * n <= 400:
        return float(np.abs(np.linalg.eigvals(np.einsum("t,tij,tkl->ikjl", weights, J, J).reshape(n * n, n * n))).max())

    def apply(x):
        return np.einsum("t,tij,jk,tlk->il", weights, J, x.reshape(n, n), J, optimize=True).ravel()

    op = LinearOperator((n * n, n * n), matvec=apply, dtype=np.float64)
    return float(np.abs(eigs(op, k=1, which="LM", return_eigenvectors=False, tol=1e-8)).max())


def moving_part(J: np.ndarray, mean: np.ndarray) -> np.ndarray | None:
    """``J`` (T, n, n) on the subspace that moves: without the modes the mean map ``mean`` leaves alone (nu = 1:
    DGTD's multipliers when nothing is heard, a tracking method's conserved sum), which would give the second moment
    radius 1 at every step. Right fixed vectors are quotiented out and left ones (conserved quantities) restricted
    away, exact where every sample fixes them as the mean does; None where one does not."""
    from scipy.linalg import null_space

    eye = np.eye(len(mean))
    right, left = null_space(mean - eye, rcond=LEFT_ALONE), null_space(mean.T - eye, rcond=LEFT_ALONE)
    if not right.size and not left.size:
        return J
    fixed = all(np.allclose(Jt @ right, right, atol=1e-9) and np.allclose(left.T @ Jt, left.T, atol=1e-9) for Jt in J)
    if not fixed:
        return None
    Q = null_space(np.concatenate([right, left], axis=1).T)
    return Q.T @ J @ Q


def second_moment_step(algorithm, known: tuple, hi: float) -> float:
    """The largest alpha up to ``hi`` at which the second moment of one agent's update on its own samples contracts
    (lam = 0: the part of the noise the mixing does not average away; `second_moment_radius` of the `moving_part`),
    by bisection; ``hi`` itself where the analysis does not apply (a mode left alone that a sample moves) or is too
    much work (`SECOND_MOMENT_WORK`, `SECOND_MOMENT_KINDS`)."""
    mean = MeanMap(algorithm, known)
    n = mean(hi, 0.0).shape[0]
    maps, weights = one_transition_maps(algorithm, known, min(SECOND_MOMENT_KINDS, SECOND_MOMENT_WORK / n**3))

    def radius(alpha: float) -> float:
        J = moving_part(np.stack([m(alpha, 0.0) for m in maps]), mean(alpha, 0.0))
        return 0.0 if J is None or not J.shape[1] else second_moment_radius(J, weights)

    if not maps or radius(hi) < 1.0:
        return hi
    lo = 0.0
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if radius(mid) < 1.0 else (lo, mid)
    return lo


def first_of(algorithm) -> float:
    """alpha_0 of the algorithm's schedule (k = 0)."""
    return float(step_sizes(algorithm.schedule, algorithm.alpha0, algorithm.beta, 0, 1)[0])


def from_the_problem(algorithm, moments, network) -> tuple:
    """(the algorithm with its first step at most `first_step`'s, the header's line saying so, or "" where it was).
    The offset beta is raised (alpha0, and so the late steps, kept); a constant step is lowered to it."""
    alpha_1, why = first_step(algorithm, moments, network)
    first = first_of(algorithm)
    if alpha_1 is None:
        return algorithm, f"steps from the problem: none, {why}; the steps given are kept"
    if first <= alpha_1:
        return algorithm, ""
    if algorithm.schedule == "constant":
        derived = replace(algorithm, alpha0=float(f"{alpha_1:.3g}"))
        change = f"the constant step {derived.alpha0:g} (not {algorithm.alpha0:g})"
    else:
        power = 2.0 if algorithm.schedule == "sqrt" else 1.0
        beta = float(f"{(algorithm.alpha0 / alpha_1) ** power:.3g}")
        derived = replace(algorithm, beta=beta)
        change = f"the offset beta {beta:g} (not {algorithm.beta:g}) makes the first step {first_of(derived):.3g}"
    return derived, f"steps from the problem: {change}, {why}; --beta or --alpha0 set them yourself"
