"""Command-line options shared by `dgtd run`, `dgtd sweep` and `dgtd compare`: a user's simulator or recordings."""

from __future__ import annotations

import click

from dgtd.config import DEFAULT_GAMMA


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


def with_env_options(f):
    """Decorate a command with `env_options`."""
    for option in reversed(env_options()):
        f = option(f)
    return f


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
