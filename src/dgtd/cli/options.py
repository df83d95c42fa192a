"""Command-line options that set fields of the run's configuration (`dgtd.config.RunConfig`), by their flat names
(`dgtd.config.FLAT`): one table, `RUN_OPTIONS`, from which `dgtd run`, `dgtd sweep`, `dgtd solve` and `dgtd compare`
each take theirs, so that an option means the same everywhere. Defaults are the config's (None: the scenario's value,
else the library's default, shown in the help) and choices `dgtd.config.CHOICES`; tests/config/test_config_cli.py
checks both."""

from __future__ import annotations

import click

from dgtd.config import CHOICES, DEFAULT_GAMMA


def shown(name: str) -> str:
    """The default an option of the run's length (`dgtd.config.RunLength`) stands for. The option's own default is
    None, the config's ('not given': an experiment file's value stays); `dgtd.run.loop.RunSettings`' applies."""
    from dgtd.run.loop import RunSettings

    return f"  [default: {getattr(RunSettings, name)}]"


def _named(option_list) -> dict:
    """{flat name: option decorator}: the name is the parameter's, as click derives it."""
    out = {}
    for option in option_list:

        @option
        def probe():  # a throw-away command, to read the parameter's name from
            pass

        out[probe.__click_params__[0].name] = option
    return out


def _run_options() -> dict:
    return _named(
        [
            click.option("--algorithm", type=str, default=None, help="Algorithm name (default: the scenario's, dgtd)."),
            click.option(
                "--iterations", "-T", type=int, default=None, help="Number of iterations T (default: the scenario's)."
            ),
            click.option("--seeds", type=int, default=None, help="Independent runs, side by side." + shown("seeds")),
            click.option(
                "--seed",
                type=int,
                default=None,
                help="Base seed; seed k draws from the keyed streams of key (seed, k)." + shown("seed"),
            ),
            click.option(
                "--alpha0",
                type=float,
                default=None,
                help="Step-size scale alpha0 (default: the scenario's; DGTD's own is 10, for features of unit "
                "scale: lower it in proportion to |phi(s)|^2).",
            ),
            click.option(
                "--beta",
                type=float,
                default=None,
                help="Step-size offset beta in alpha0/sqrt(k+beta) (default: the scenario's; DGTD's own is 1000).",
            ),
            click.option(
                "--schedule",
                type=click.Choice(CHOICES["schedule"]),
                default=None,
                help="alpha0/sqrt(k+beta) (the paper's), alpha0/(k+beta), or constant alpha0.",
            ),
            click.option(
                "--sampling",
                type=click.Choice(CHOICES["sampling"]),
                default=None,
                help="i.i.d. s ~ d or Markovian trajectories.",
            ),
            click.option(
                "--shared/--independent",
                default=None,
                help="All agents observe one state trajectory (scenario 1), or each its own copy (scenario 2).",
            ),
            click.option(
                "--reward-noise",
                type=click.Choice(CHOICES["reward_noise"]),
                default=None,
                help="How a sample's reward is drawn: its mean E[r | s, a] (none, the default), random in "
                "[0, sigma] with that mean (bernoulli, uniform), or the reward of the sampled transition "
                "r(s, a, s') where the problem gives rewards per transition (transition).",
            ),
            click.option(
                "--restarts",
                type=click.Choice(CHOICES["restarts"]),
                default=None,
                help="An episodic task's restart transition (terminal state to the next episode's start) is a sample, "
                "as dgtd counts it (sampled, the default), or not, as RL-Glue based suites count it (skipped; d then "
                "weights the non-terminal states only). See README, Episodic tasks.",
            ),
            click.option(
                "--backend",
                type=click.Choice(CHOICES["backend"]),
                default=None,
                help="The compiled kernels (numba), the NumPy reference, or JAX on its device (the extra dgtd[jax]; "
                "perfect and lossy links): the same numbers." + shown("backend"),
            ),
            click.option(
                "--asynchronous/--synchronous",
                default=None,
                help="Under mpiexec: ranks do not wait for each other's messages, each agent using the newest "
                "received (their ages are recorded); synchronous (the default) gives one process's numbers.",
            ),
            click.option(
                "--staleness",
                type=int,
                default=None,
                help="With --asynchronous: a rank waits for a neighbour's message once the newest it has is more "
                "than S steps old (default: never waits; 0: the synchronous numbers).",
            ),
            click.option(
                "--checkpoints",
                type=int,
                default=None,
                help="How many times to record metrics (at most once per iteration)." + shown("checkpoints"),
            ),
            click.option(
                "--tail-fraction",
                type=float,
                default=None,
                help="Final fraction of the run averaged for w_tail." + shown("tail_fraction"),
            ),
            click.option(
                "--block-size",
                type=int,
                default=None,
                help="Steps drawn and advanced per block (no effect on results)." + shown("block_size"),
            ),
            click.option(
                "--problem",
                "problem_file",
                type=str,
                default=None,
                help="An .npz with arrays P (S,S), R (N,S), Phi (S,q) and scalar gamma, instead of a scenario.",
            ),
            click.option(
                "--graph",
                type=str,
                default=None,
                help="ring, path, star, complete, erdos-renyi, or a file of 'i j' edge lines (default: the "
                "scenario's, else ring).",
            ),
            click.option(
                "--edge-prob",
                type=float,
                default=None,
                help="Probability that each edge of the graph is up at each step (1 = fixed graph).",
            ),
            click.option(
                "--loss",
                type=str,
                default=None,
                metavar="P|P1,...,PN|FILE",
                help="Each message is lost with probability P; or agent i misses each message sent to it with "
                "probability Pi (one per agent); or a file of 'i j p' lines (agent i misses j's messages with "
                "probability p). Default: none lost. See docs/links.md.",
            ),
            click.option(
                "--burst",
                type=float,
                default=None,
                metavar="L",
                help="Lost messages come in bursts of mean length L on each link (Gilbert-Elliott), with the same "
                "long-run loss as --loss. Default: each message lost independently.",
            ),
            click.option(
                "--reweight/--no-reweight",
                default=None,
                help="Each agent weighs what it hears from j by 1 / (1 - loss of j's messages to it): the Laplacian "
                "methods (dgtd, pd-td) then converge to w* under any --loss. Default: no.",
            ),
            click.option(
                "--delay",
                type=int,
                default=None,
                metavar="D",
                help="Each message arrives d steps late, d uniform in 0..D; a receiver uses the newest it holds from "
                "each neighbour. Default: 0.",
            ),
            click.option(
                "--wake",
                type=str,
                default=None,
                metavar="Q|Q1,...,QN",
                help="Each agent is awake at a step with probability Q (or Qi, one per agent); asleep, it neither "
                "updates nor sends, and its neighbours use the last they heard. Default: 1.",
            ),
            click.option(
                "--bits",
                type=int,
                default=None,
                metavar="B",
                help="Each number sent is rounded stochastically to B bits, the message's scale sent alongside. "
                "Default: 64 (exact).",
            ),
            click.option(
                "--top-k",
                type=int,
                default=None,
                metavar="K",
                help="Each message keeps its K largest coordinates (with their indices). Default: all.",
            ),
            click.option(
                "--error-feedback/--no-error-feedback",
                default=None,
                help="Send the compressed difference from a copy both ends keep (CHOCO-gossip), so that what is "
                "not sent now is sent later. Default: no.",
            ),
            click.option(
                "--kappa",
                type=float,
                default=None,
                help="Weight of the consensus term of the Lagrangian (section 5; default: the scenario's, DGTD's own "
                "is 3).",
            ),
            click.option(
                "--rho", type=float, default=None, help="Regulariser (rho/2)|mu|^2 - (rho/2)|w|^2 (0 = none)."
            ),
            *env_options(),
        ]
    )


def run_options(*names: str):
    """Decorate a command with the options of ``names`` from `RUN_OPTIONS` (all of them when none are named), in
    the table's order."""

    def decorate(f):
        chosen = [option for name, option in RUN_OPTIONS.items() if not names or name in names]
        for option in reversed(chosen):
            f = option(f)
        return f

    return decorate


def _split(ctx, param, value):
    """--split: 'random' or shares 'w_1,...,w_N' (a list)."""
    if value is None or value == "random":
        return value
    try:
        return [float(x) for x in value.split(",")]
    except ValueError:
        raise click.BadParameter(
            f"give 'random' or the agents' shares separated by commas, e.g. 0.5,0.3,0.2; got {value!r}"
        ) from None


def env_options() -> list:
    """The user's own simulator (--env ...) or recordings (--data FILE); see docs/environments.md."""
    from dgtd.scenarios.user import FEATURES_HELP, EnvSpec

    return [
        click.option(
            "--env",
            "env_make",
            type=str,
            default=None,
            metavar="MODULE:FUNCTION",
            help="Run on your own simulator: a function returning a PettingZoo ParallelEnv or a Gymnasium env "
            "(module.path:make_env, path/to/file.py:make_env, or gymnasium:ENV-ID). More fields in "
            "an experiment file's [env] table.",
        ),
        click.option(
            "--features",
            type=str,
            default=None,
            help=f"The env's linear features: {FEATURES_HELP} (default {EnvSpec.features}).",
        ),
        click.option(
            "--policy",
            type=str,
            default=None,
            help=f"The env's policy: random, or module:function(agent, observation, space, rng) -> action "
            f"(default {EnvSpec.policy}).",
        ),
        click.option(
            "--agents",
            type=int,
            default=None,
            help="Number of agents: of the scenario (mpe-spread), of your env's function, or the agents a "
            "Gymnasium env's reward is split among.",
        ),
        click.option(
            "--split",
            type=str,
            default=None,
            callback=_split,
            help="How a Gymnasium env's one reward is split: random (fresh shares at every step, averaging to "
            "the reward) or the agents' shares, e.g. 0.5,0.3,0.2.",
        ),
        click.option(
            "--data",
            type=str,
            default=None,
            metavar="FILE",
            help="Run on recorded transitions (.parquet, .csv, .npz; columns seed, step, agent, phi_j, "
            "next_phi_j (or state, next_state), reward, and optionally ratio, terminal): one recording per "
            "seed.",
        ),
        click.option(
            "--gamma",
            type=float,
            default=None,
            help=f"Discount factor of an --env or --data run (default {DEFAULT_GAMMA}).",
        ),
    ]


RUN_OPTIONS = _run_options()
"""Flat field name (or [env] flag) -> its option: the one definition of every run option."""
LINK_OPTIONS = ("loss", "burst", "reweight", "delay", "wake", "bits", "top_k", "error_feedback")
"""The links' options (`dgtd.config.NetworkConfig`), which run, sweep, solve and compare all take."""
ENV_OPTIONS = tuple(_named(env_options()))
"""The options of a user's simulator or recordings (--env, --features, ..., --data, --gamma)."""
