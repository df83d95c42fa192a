"""The JAX backend (``--backend jax``, the optional extra ``dgtd[jax]``): every algorithm's one definition
(`dgtd.algorithms.base`) run by JAX in float64, seeds and agents as array axes, a block's steps in one `jax.lax.scan`,
compiled once per run and block length, on a GPU where JAX has one, else on the CPU.

The contract is `dgtd.backends.reference.run_block`'s, and so are the numbers (to rounding: tested to 1e-12): the
samples are the same block of the seeds' keyed streams, drawn on the host, and the links that deliver at each step
are the channel's own (`deliver`, run on the host for the block's steps, which also counts the messages and bits),
so a seed gives the same samples and the same links on every backend. Every channel whose receivers hold no copies
runs here (`dgtd.channels.base.Channel.holds`: the perfect and lossy links, with losses, bursts and reweighting);
late, asleep and compressed messages are refused in one line (`check_supported`).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from dgtd.channels import Inbox
from dgtd.errors import DgtdInputError
from dgtd.samples import Block, Sample


def available() -> bool:
    try:
        import jax  # noqa: F401
    except ImportError:
        return False
    return True


def on_cpu() -> bool:
    """Whether JAX runs on this machine's CPU (it found no GPU or other accelerator)."""
    import jax

    return jax.default_backend() == "cpu"


ON_CPU = (
    "note: JAX runs on this machine's CPU (it found no GPU); on a CPU it is the slowest backend here (a new user "
    "measured paper-example-1 at 51.7 s against 9.8 s for numpy and 2.0 s for numba), and --backend numba gives the "
    "same numbers to rounding"
)


def check_supported(channel) -> None:
    """One line where this backend cannot run a run: JAX missing, or a link model it does not run."""
    if not available():
        raise DgtdInputError(
            "--backend jax needs JAX: pip install 'dgtd[jax]' (or jax[cuda12] for a GPU), or use --backend numba"
        )
    if channel.holds:
        raise DgtdInputError(
            f"--backend jax runs perfect and lossy links (--loss, --burst, --reweight), not {channel.describe()}: "
            "use --backend numba or numpy for late, asleep or compressed messages"
        )


def run_block(ctx, state, channel_state, w_sum: np.ndarray, alphas: np.ndarray, blk: Block):
    """Advance ``ctx.algorithm`` over the len(alphas) steps of ``blk`` on JAX's device: (state, channel state,
    w_sum), NumPy arrays, as `dgtd.backends.reference.run_block` returns them."""
    jnp = _jax().numpy
    algorithm, channel, arcs = ctx.algorithm, ctx.channel, ctx.arcs
    T, B, q = len(alphas), w_sum.shape[0], w_sum.shape[2]
    Phi, ratio, continuing = (ctx.Phi, ctx.ratio, ctx.continuing) if blk.table is None else blk.table
    # the links: what each arc delivers at each step, by the channel's own deliver (which counts them too)
    shapes = {name: np.zeros((B, 0, q)) for name in algorithm.messages}
    heard = np.zeros((T, B, arcs.n_arcs))
    weights = None
    for t in range(T):
        inbox, channel_state = channel.deliver(channel_state, arcs, shapes, None if blk.up is None else blk.up[t])
        if inbox.received or inbox.awake is not None:  # values or sleepers beyond what the JAX step reads
            raise DgtdInputError(f"--backend jax runs links that deliver what was sent, not {channel.describe()}")
        heard[t], weights = inbox.heard, inbox.weights
    if T == 0:
        return state, channel_state, w_sum
    block = _block(algorithm, arcs, float(ctx.gamma), continuing is not None, weights is not None)
    steps = tuple(jnp.asarray(x) for x in (blk.s, blk.a, blk.s_next, blk.r, heard, np.asarray(alphas, np.float64)))
    tables = tuple(jnp.asarray(x) for x in (Phi, ratio, np.ones(1) if continuing is None else continuing))
    new, w_sum = block(
        type(state)(*(jnp.asarray(x) for x in state)),
        jnp.asarray(w_sum),
        steps,
        tables,
        jnp.asarray(np.zeros(0) if weights is None else weights),
    )
    return type(state)(*(np.array(x) for x in new)), channel_state, np.array(w_sum)


def _jax():
    """JAX, computing in float64 as the other backends do."""
    import jax

    jax.config.update("jax_enable_x64", True)
    return jax


@lru_cache(maxsize=16)
def _block(algorithm, arcs, gamma: float, episodic: bool, reweighs: bool):
    """The block's steps as one compiled function of (state, w_sum, the steps' samples and links, the tables, the
    arcs' weights): the reference's loop body under `jax.lax.scan`."""
    jax = _jax()

    def block(state, w_sum, steps, tables, weights):
        Phi, ratio, continuing = tables

        def step(carry, now):
            state, w_sum = carry
            s, a, sn, r, heard, alpha = now
            w_sum = w_sum + algorithm.estimate(state)
            discount = gamma * continuing[s] * continuing[sn] if episodic else gamma
            sample = Sample(Phi[s], Phi[sn], r, ratio[s, a], discount)
            inbox = Inbox(arcs, algorithm.sends(state), heard, weights=weights if reweighs else None)
            return (algorithm.update(state, sample, inbox, alpha), w_sum), None

        (state, w_sum), _ = jax.lax.scan(step, (state, w_sum), steps)
        return state, w_sum

    return jax.jit(block)
