"""What a run records at its checkpoints (`measure`): every metric against the exact references, combined over the
agents by the layout (one process or ranks), the counts beside them, and seeds that diverge stopped (`stop_diverged`).
"""

from __future__ import annotations

import numpy as np

from dgtd.problems import exact

# The metrics recorded at every checkpoint, (C, B) each: the worst agent's relative error and value error of its last,
# averaged and tail-averaged iterates, the consensus error, and the (root) MSPBE
METRICS = (
    "error_last",
    "error_avg",
    "error_tail",
    "value_error_last",
    "value_error_avg",
    "value_error_tail",
    "consensus",
    "mspbe_last",
    "mspbe_avg",
    "rmspbe_last",
    "rmspbe_avg",
    "rmspbe_tail",
)
# Counts recorded at every checkpoint beside the metrics (in RunResult.info["counts"], arrays (C, B)): agent-samples
# consumed, the messages (vectors of q numbers) and bits the channel delivered, 1 once diverged.
COUNTS = ("samples", "messages", "bits", "diverged")
DIVERGENCE_FACTOR = 1e6  # a seed has diverged when |w|_inf exceeds this times max(1, |w*|_inf, |w0|_inf)


def measure(plan, rs) -> None:
    """Row c of the metrics and counts at checkpoint step k (NaN for seeds that have diverged), the running sum kept
    for the tail averages and the estimates for the trajectory (filled in place)."""
    c, k, steps = rs.c, rs.k, plan.steps
    alive = rs.diverged_at < 0
    w, w_avg = plan.algorithm.estimate(rs.state), rs.w_sum / k
    for x in (*rs.metrics.values(), *rs.counts.values()):
        x[c] = np.nan
    rs.agent_error_last[c], rs.agent_error_avg[c] = np.nan, np.nan
    if alive.any():
        _errors(plan, rs, w[alive], w_avg[alive], alive)
        if rs.sum_trace is not None:
            rs.sum_trace[c] = rs.w_sum
            _tail_errors(plan, rs, tail_at(c, steps, rs.sum_trace, plan.settings.tail_fraction)[alive], alive)
        counts = rs.counts
        counts["samples"][c, alive] = plan.n_agents * k  # one sample per agent per step, for every algorithm
        counts["messages"][c, alive] = rs.messages[alive]
        counts["bits"][c, alive] = rs.bits[alive]
    rs.counts["diverged"][c] = ~alive
    if plan.keep_trace:
        whole = plan.layout.whole(w)  # (a collective where the agents are spread)
        if rs.w_trace is not None:
            rs.w_trace[c] = whole


def _errors(plan, rs, w: np.ndarray, w_avg: np.ndarray, alive: np.ndarray) -> None:
    """The last and averaged iterates' errors of the live seeds at checkpoint c."""
    c, m, moments, worst = rs.c, rs.metrics, plan.moments, plan.layout.worst
    rs.agent_error_last[c, alive] = plan.relative_error(w)
    rs.agent_error_avg[c, alive] = plan.relative_error(w_avg)
    m["error_last"][c, alive] = worst(rs.agent_error_last[c, alive])
    m["error_avg"][c, alive] = worst(rs.agent_error_avg[c, alive])
    m["value_error_last"][c, alive] = worst(plan.value_error(w))
    m["value_error_avg"][c, alive] = worst(plan.value_error(w_avg))
    m["consensus"][c, alive] = plan.layout.consensus(w)
    m["mspbe_last"][c, alive] = worst(exact.mspbe(moments, w))
    m["mspbe_avg"][c, alive] = worst(exact.mspbe(moments, w_avg))
    m["rmspbe_last"][c, alive] = worst(exact.rmspbe(moments, w))
    m["rmspbe_avg"][c, alive] = worst(exact.rmspbe(moments, w_avg))


def _tail_errors(plan, rs, w_tail: np.ndarray, alive: np.ndarray) -> None:
    c, m, worst = rs.c, rs.metrics, plan.layout.worst
    m["error_tail"][c, alive] = worst(plan.relative_error(w_tail))
    m["value_error_tail"][c, alive] = worst(plan.value_error(w_tail))
    m["rmspbe_tail"][c, alive] = worst(exact.rmspbe(plan.moments, w_tail))


def stopped(rs) -> None:
    """Every later row NaN (and diverged), once every seed has diverged: nothing is left to run."""
    c = rs.c
    for x in (*rs.metrics.values(), *rs.counts.values()):
        x[c:] = np.nan
    rs.counts["diverged"][c:] = 1.0
    rs.agent_error_last[c:], rs.agent_error_avg[c:] = np.nan, np.nan
    if rs.w_trace is not None:
        rs.w_trace[c:] = np.nan


def stop_diverged(state, sums, w: np.ndarray, limit: float, diverged_at: np.ndarray, k: int, any_=None):
    """Mark seeds whose estimate is not finite or exceeds ``limit`` as diverged at step k (in place in
    ``diverged_at``) and stop them: their state and sums become NaN, which every kernel carries along. ``any_``:
    whether any rank found a seed so (the layout's `any`), where the agents are spread."""
    bad = ~np.all(np.isfinite(w), axis=(1, 2)) | (np.nan_to_num(np.abs(w), nan=np.inf).max(axis=(1, 2)) > limit)
    for x in state:
        bad |= ~np.all(np.isfinite(x.reshape(x.shape[0], -1)), axis=1)
    bad = bad if any_ is None else any_(bad)
    new = bad & (diverged_at < 0)
    if not new.any():
        return state, sums
    diverged_at[new] = k
    state = type(state)(*(np.where(new[:, None, None], np.nan, x) for x in state))
    sums = {key: np.where(new[:, None, None], np.nan, v) for key, v in sums.items()}
    return state, sums


def tail_at(c: int, steps: np.ndarray, sum_trace: np.ndarray, fraction: float) -> np.ndarray:
    """The tail average at checkpoint c: the mean of w_j over the steps since the latest checkpoint at or before
    (1 - fraction) k_c (all of them when there is none), from the running sums recorded at the checkpoints; it
    approximates the final `RunResult.w_tail` at the last checkpoint, where the window is (1 - fraction) T exactly."""
    k = steps[c]
    before = np.flatnonzero(steps[:c] <= (1.0 - fraction) * k)
    if before.size == 0:
        return sum_trace[c] / k
    j = before[-1]
    return (sum_trace[c] - sum_trace[j]) / (k - steps[j])
