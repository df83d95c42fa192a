"""`dgtd learn`: agents that improve their policies, each with one of dgtd's distributed critics (`dgtd.run.learn`)."""

from __future__ import annotations

import sys
from dataclasses import fields
from pathlib import Path

import click

from dgtd.cli.options import declared_option, make_option, output_options, run_options
from dgtd.config import field_types
from dgtd.errors import DgtdInputError
from dgtd.learning import ENV_TASKS, SHARED, LearnConfig


def learn_options():
    """`LearnConfig`'s fields as options, their defaults shown."""
    hints = field_types(LearnConfig)
    chosen = [
        make_option(f.name, f, hints[f.name], declared_option(f)["help"], None, False, _choices(f.name))
        for f in fields(LearnConfig)
    ]

    def decorate(command):
        for option in reversed(chosen):
            command = option(command)
        return command

    return decorate


LEARN_HELP = {  # the options shared with `dgtd run` whose meaning or default differs here (its help described run's)
    "problem_file": "A multi-agent MDP file (.npz): P (S, A, S) over joint actions, R (N, S, A) or (N, S, A, S), Phi "
    "(S, q), gamma and one starting policy policy_i (S, A_i) per agent.",
    "alpha0": "The critics' step-size scale alpha0 (default 1 on a task or problem file, 0.1 in a simulator).",
    "beta": "The critics' step-size offset beta in alpha0/sqrt(k+beta) (default 100).",
    "gamma": "The critics' discount in a simulator (--env, mpe-spread; default 0.9); a team MDP task or problem "
    "file has its own.",
}


def _choices(name: str):
    from dgtd.run.learn import ACTORS, OBJECTIVES, SCHEMES, TEAM_REWARDS, VALUES

    choices = {"actor": ACTORS, "values": VALUES, "objective": OBJECTIVES, "team_reward": TEAM_REWARDS}
    return (choices | {"scheme": SCHEMES}).get(name)


@click.command()
@click.argument("task", required=False)
@learn_options()
@run_options(*SHARED)
@output_options("out", "progress", "plots", "overwrite", "checkpoint_every", "log")
@click.option(
    "--ranks",
    type=int,
    default=None,
    help="Spread the agents over R processes: starts the mpi extra's mpiexec -n R (each holds its agents' actors, "
    "critics and estimates; the numbers are one process's, bit for bit).",
)
@click.option(
    "--resume",
    "resume_dir",
    type=click.Path(file_okay=False),
    default=None,
    help="Continue the learning run in DIR (its config.toml: the options it was given) from its last checkpoint; "
    "ends with the numbers of an uninterrupted run. With a larger -T, a finished run that ran with "
    "--checkpoint-every goes on from its end to the numbers of a run of that length.",
)
@click.pass_context
def learn(ctx, task, out, progress, plots, overwrite, checkpoint_every, log, ranks, resume_dir, **values):
    """Agents that learn their policies on TASK (pull-away, zhang-20, factored; the simulator mpe-spread), --problem
    FILE (a multi-agent MDP file, P (S, A, S), with one starting policy per agent) or --env module:make_env (a user's
    PettingZoo simulator, its critics' --features as for `dgtd run`), each with its own softmax policy
    and one of dgtd's distributed critics (--algorithm, DGTD by default) over the network and links given as for `dgtd
    run`; writes config.toml (what was asked: `--resume DIR` continues it), summary.json (the last policies and their
    exact return beside the best), metrics.csv and returns.png (docs/control.md)."""

    from dgtd.learning import resolve_learning
    from dgtd.run import runtime

    if resume_dir is not None:
        resumed = _resumed(ctx, resume_dir, out, overwrite)
        if resumed is None:
            return
        task, values, out, checkpoint_every, log = resumed
    if log:
        from dgtd.run.logs import log_kinds

        log_kinds(log)  # (an unknown or missing logger: one line before anything runs)
    if checkpoint_every is not None:  # (a negative one ran and saved nothing)
        from dgtd.run.settings import check_count

        checkpoint_every = check_count("checkpoint_every", checkpoint_every, 0)
    simulator = task if task in ENV_TASKS else values.get("env_make")
    if (simulator is not None or values.get("scheme") == "chen") and (ranks is not None or checkpoint_every):
        what = "Chen et al.'s Algorithm 1 (--scheme chen)" if simulator is None else f"{simulator} is a simulator,"
        raise DgtdInputError(
            f"{what} run in one process: its state cannot be saved or split (no --ranks, --checkpoint-every)"
        )
    if ranks is not None:
        from dgtd.cli.launch import ARGV, launch

        raise SystemExit(launch(ranks, None, ARGV))
    job = resolve_learning(task, values)
    problem = job.env if job.env is not None else job.mdp
    out = Path(out) if out else Path("runs") / f"learn-{problem.name}-{job.settings.actor}"
    _header(job, values.get("backend"))
    held: list = []  # the results folder's lock, held by the process that writes
    resume = runtime.claimed(
        lambda: _claim(out, job, overwrite, held, {"checkpoint_every": checkpoint_every, "log": log}, resume_dir),
        lambda: _checkpoint(out, job, overwrite, resume_dir is not None),
    )
    try:
        _timescales(job)  # (after the folder's checks: a refusal is one line)
        if resume is not None and _ended_at(resume) == resume["k"] < job.settings.iterations:
            click.echo(f"extending the finished learning run in {out} from {int(resume['k']):,} to "
                       f"{job.settings.iterations:,} steps")  # fmt: skip
        elif resume is not None:
            click.echo(f"resuming {out} at step {int(resume['k']):,}")
        result = _learning(job, out, progress, checkpoint_every or 0, resume)
        if not runtime.writes():
            return
        written = _write(out, result, job, plots, log, keep=bool(checkpoint_every))
    finally:
        for owner in held:
            owner.__exit__(None, None, None)
    _report(result, job)
    click.echo(f"wrote {out}/{', '.join(written)} ({result.seconds:.1f} s)")


LEARNERS_ON_CPU = (
    "JAX runs on this machine's CPU (it found no GPU), where it is the slowest backend for learners (pull-away, "
    "3 000 steps: 7.1 s against 2.0 s for numpy); --backend numba or numpy give the same numbers to rounding"
)


def _header(job, backend) -> None:
    """What will run, in two lines, and the notes on how (the backend it runs on, a slow size)."""
    s = job.settings
    if job.env is not None:
        task = job.env
        click.echo(f"{task.name}: {task.n_agents} agents; critics: {_critics_of(s.objective, task.gamma)}; network: "
                   f"{job.network.describe()}; {job.channel.describe()}")  # fmt: skip
        click.echo(
            f"{_actors(s)} (softmax linear in their own observations) with the {job.critic.name} critic "
            f"({job.critic.describe()}); {job.actor.describe(s.iterations)}; {s.iterations:,} steps x {s.seeds} "
            "seed(s)"
        )
        if backend in ("numba", "jax"):
            click.echo(
                "note: learners in a simulator run on the NumPy backend (the simulator's step is the cost)", err=True
            )
        return
    mdp = job.mdp
    click.echo(
        f"{mdp.name}: {mdp.n_states} states, {mdp.n_agents} agents, {_actions(mdp.actions)}; objective: "
        f"{_objective(s.objective, mdp.gamma)}; network: {job.network.describe()}; {job.channel.describe()}"
    )
    if job.chen is not None:
        c = job.chen
        click.echo(
            f"Chen et al.'s Algorithm 1: {s.iterations // c.samples:,} iterations of {c.critic_batches} x "
            f"{c.critic_batch} critic samples (beta {c.critic_step:g}, {c.critic_rounds} consensus rounds) and "
            f"{c.batch} actor samples (alpha {c.actor_step:g}, {c.reward_rounds} rounds on each reward), "
            f"{s.seeds} seed(s)"
        )
        return
    click.echo(
        f"{_actors(s)} with the {job.critic.name} critic ({job.critic.describe()}); "
        f"{job.actor.describe(s.iterations)}; {s.iterations:,} steps x {s.seeds} seed(s) on the {s.backend} backend"
    )
    if s.backend == "numba":
        from dgtd.run.learn import fallback

        why = fallback(job.critic, job.channel)
        if why is not None:
            click.echo(f"note: {why}", err=True)
    if s.backend == "jax":
        from dgtd.backends import jax as on_jax

        if on_jax.available() and on_jax.on_cpu():
            click.echo(f"note: {LEARNERS_ON_CPU}", err=True)
    size = mdp.n_agents * mdp.n_states * max(mdp.actions)
    if s.actor == "networked" and s.team_reward == "regression" and mdp.n_agents * size > ESTIMATE_NOTE:
        click.echo(
            f"note: networked agents each keep an estimate of the team's reward of N S A = {size:,} numbers, "
            f"{mdp.n_agents * size:,} in all, mixed at every step (Zhang et al.'s Algorithm 2 with additive features): "
            "slow at this size (1 000 agents of 10 states: about 0.2 s a step on 2 cores, compiled); --team-reward "
            "neighbourhood keeps one of the degree's size",
            err=True,
        )


def _resumed(ctx, resume_dir, out, overwrite) -> tuple | None:
    """(task, option values, folder, --checkpoint-every, --log) of the learning run in ``resume_dir``, from its
    config.toml (options typed beside --resume override it: the checkpoint then refuses a run that differs), or None
    where it finished (said)."""
    import tomllib

    from dgtd.cli.options import given_flags, resume_folder

    folder = resume_folder(resume_dir, out, "learning run", "dgtd learn TASK")
    if overwrite:
        raise DgtdInputError("--resume continues the saved run and --overwrite starts it afresh: give one, not both")
    try:
        saved = dict(tomllib.loads((folder / CONFIG).read_text(encoding="utf-8-sig")).get("learn", {}))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError, OSError) as e:
        raise DgtdInputError(f"--resume {folder}: its {CONFIG} cannot be read ({e}); start the run afresh") from None
    names = set(ctx.params) - {"task", "resume_dir", "ranks", "out", "progress", "plots", "overwrite"}
    unknown = sorted(set(saved) - names - {"task"})
    if unknown:
        raise DgtdInputError(f"--resume {folder}: its {CONFIG} names options dgtd learn has not: {', '.join(unknown)}")
    given = given_flags(ctx, exclude=("task", "resume_dir", "ranks", "out", "progress", "plots", "overwrite"))
    values = {name: saved.get(name) for name in names} | given
    task = ctx.params["task"] if ctx.params["task"] is not None else saved.get("task")
    if _finished(folder, values):
        click.echo(f"{folder}: the learning run is already finished (summary.json); nothing to resume")
        return None
    own = {k: v for k, v in values.items() if k not in OUTPUT}
    return task, own, folder, values.get("checkpoint_every"), values.get("log")


def _finished(folder: Path, values: dict) -> bool:
    """Whether the learning run in ``folder`` has ended at the steps ``values`` ask (its summary.json's); more steps
    extend it where it kept its state at its end (`_checkpoint`), and are refused where it kept none."""
    from dgtd.run.extend import without_state
    from dgtd.run.results import saved_config

    summary = folder / "summary.json"
    if not summary.exists():
        return False
    done, asked = _steps(saved_config(summary)), _steps({k: v for k, v in values.items() if v is not None})
    if done.get("iterations") == asked["iterations"]:
        return True
    if not (folder / CHECKPOINT).exists():
        without_state(folder, done, asked, "learning run", f"dgtd learn {values.get('task') or 'TASK'} --out {folder}")
    return False


def _steps(record: dict) -> dict:
    """A learning run's record with its steps (-T) as run, given or not (`dgtd.learning.ITERATIONS` by default)."""
    from dgtd.learning import ITERATIONS

    return {**record, "iterations": int(record.get("iterations") or ITERATIONS)}


def _learning(job, out: Path, progress: bool, checkpoint_every: int, resume: dict | None):
    """The learning run (`dgtd.run.learn.learn`) with its progress bar, its time said where long (`CostProbe`), its
    checkpoints kept (without --checkpoint-every, on one process, its state saved every `SAVE_SECONDS` by time, so
    that a long run cut off continues by the same command), and metrics.csv written as measured (on Ctrl-C too)."""
    from tqdm import tqdm

    from dgtd.run import runtime
    from dgtd.run.schemes import run_job

    s, done = job.settings, 0 if resume is None else int(resume["k"])
    bar = tqdm(total=s.iterations, disable=not progress, file=sys.stderr, unit="it", unit_scale=True, mininterval=0.5)
    bar.update(done)
    by_time = not checkpoint_every and job.env is None and job.chen is None and not runtime.in_job()
    probe = CostProbe(s.iterations, done, saves=SAVE_SECONDS if by_time else 0.0)

    def advance(n: int) -> None:
        bar.update(n)
        probe(n)

    def keep(snap: dict) -> None:  # every rank its shard, where the agents are spread
        _keep(out, snap, job.record)

    measured = _measured_so_far(out, s.actor) if runtime.writes() else None
    try:
        saves = {"checkpoint_every": checkpoint_every, "on_checkpoint": keep, "resume": resume}
        return run_job(
            job, advance, measured, **saves, checkpoint_seconds=SAVE_SECONDS if by_time else 0.0
        )  # fmt: skip
    except KeyboardInterrupt:  # what was measured is kept (metrics.csv of the checkpoints so far)
        if measured is not None:
            measured.write()
        raise
    finally:
        bar.close()


def _write(out: Path, result, job, plots: bool, log: str | None = None, keep: bool = False) -> list:
    """The results of a finished learning run, numbers before pictures, each file atomically; the checkpoint gone
    unless ``keep`` (--checkpoint-every: the state at the end stays, from which a larger -T extends the run).
    A model's policies (policies.npz: (B, N, S, A_max) and each agent's action count), or a simulator's actors'
    weights (actors.npz: theta (B, N, A, d)); the metrics in the loggers ``log`` asks (`dgtd.run.logs`)."""
    import numpy as np

    from dgtd.run.atomic import atomic_write, atomic_write_json
    from dgtd.run.checkpoint import remove_checkpoint
    from dgtd.run.learn import metrics_csv, summary
    from dgtd.run.results import npz_bytes

    problem, s = job.env if job.env is not None else job.mdp, job.settings
    if not keep:  # the numbers are complete: nothing is left to resume (its shards neither)
        remove_checkpoint(out / CHECKPOINT)
    if job.env is not None:
        name, arrays = "actors.npz", {"theta": result.policies}
    else:
        name, arrays = "policies.npz", {"policies": result.policies, "actions": np.asarray(problem.actions)}
    atomic_write(out / name, npz_bytes(arrays))
    atomic_write_json(out / "summary.json", summary(result, problem, job.record))
    atomic_write(out / "metrics.csv", metrics_csv({s.actor: result}, "actor"))
    written = [name, "summary.json", "metrics.csv"]
    if log:
        from dgtd.run.learn import metrics_rows
        from dgtd.run.logs import log_kinds, write_logs

        written += write_logs(out, log_kinds(log), metrics_rows({s.actor: result}), job.record)
    if plots:
        from dgtd.plots.learning import learning_figure

        written.append(learning_figure(out, result, f"{problem.name}, {s.actor}, {job.critic.name} critic"))
    return written


class CostProbe:
    """Says once, early, how long a run will take where that is more than `LONG` seconds: the seconds a step measured
    on steps `PROBE_FROM` onwards (past the kernels' compilation) for at least `PROBE_SECONDS` or `PROBE_STEPS` steps,
    times the steps left. Call it with each step's count (as a progress bar's update); ``clock`` and ``say`` are the
    time and the output."""

    LONG, PROBE_FROM, PROBE_SECONDS, PROBE_STEPS = 60.0, 5, 1.0, 200

    def __init__(self, total: int, done: int = 0, clock=None, say=None, saves: float = 0.0):
        import time

        self.total, self.count, self.saves = total, done, saves
        self.started: float | None = None
        self.clock = clock or time.perf_counter
        self.say = say or (lambda line: click.echo(f"note: {line}", err=True))
        self.first = done + self.PROBE_FROM

    def __call__(self, n: int = 1) -> None:
        self.count += n
        if self.started is None:
            if self.count >= self.first:
                self.started, self.first = self.clock(), self.count
            return
        if self.first < 0:
            return
        elapsed, steps = self.clock() - self.started, self.count - self.first
        if elapsed < self.PROBE_SECONDS and steps < self.PROBE_STEPS:
            return
        per_step, left = elapsed / max(steps, 1), self.total - self.count
        if per_step * left > self.LONG:
            self.say(
                f"about {per_step:.3g} s a step (measured on {steps:,} steps): the {left:,} steps left take about "
                f"{_duration(per_step * left)}; -T or --agents shorten it, Ctrl-C keeps what was measured"
                + (
                    f", and its state is saved every {_duration(self.saves)}: the same command continues it"
                    if self.saves and per_step * left > self.saves
                    else ""
                )
            )
        self.first = -1  # (said once)


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} minutes"
    return f"{seconds / 3600:.1f} hours"


def _measured_so_far(out: Path, actor: str):
    """metrics.csv of the checkpoints measured so far, rewritten as they come (`dgtd.run.results.MeasuredSoFar`, in
    the learning runs' columns)."""
    from types import SimpleNamespace

    from dgtd.run.learn import metrics_csv
    from dgtd.run.results import MeasuredSoFar

    return MeasuredSoFar(
        out, actor, lambda latest: metrics_csv({actor: SimpleNamespace(steps=latest.steps, metrics=latest.metrics)},
                                               "actor"),
    )  # fmt: skip


CHECKPOINT = "learning-checkpoint.npz"
SAVE_SECONDS = 300.0  # without --checkpoint-every, a learning run on one process saves its state this often
CONFIG = "config.toml"
OUTPUT = ("checkpoint_every", "log")  # output options config.toml keeps: a resumed run saves and logs as it did
ESTIMATE_NOTE = 5_000_000  # team-reward estimates' numbers in all beyond which a networked run is said to be slow


def _keep(out: Path, snapshot: dict, record: dict) -> None:
    """The run's state at a step, in the run's checkpoint format beside what the run was asked to do (where the
    agents are spread, every rank its shard: `dgtd.run.runtime.save_learners`)."""
    from dgtd.run import runtime

    runtime.save_learners(out / CHECKPOINT, snapshot, record)


def _claim(out: Path, job, overwrite: bool, held: list, output: dict, resuming) -> dict | None:
    """The results folder claimed (its lock appended to ``held``), another run's results refused, and the checkpoint
    to resume from (`_checkpoint`), or, a run starting afresh, the last run's logs gone and config.toml written (what
    was asked, with the ``output`` settings kept, for `--resume`); a refusal leaves the folder as it found it,
    unclaimed, as `dgtd run`'s does."""
    from dgtd.run.atomic import atomic_write
    from dgtd.run.extend import other_length
    from dgtd.run.logs import remove_logs
    from dgtd.run.owner import Owner
    from dgtd.run.results import refuse_other_results, saved_config

    owner = Owner(out, "learning run", overwrite).__enter__()
    try:
        if not overwrite and not resuming:
            done = _steps(saved_config(out / "summary.json"))
            other_length(out, done, _steps(job.record), "learning run", "dgtd learn")
            refuse_other_results(out, job.record, "learning run")
        resume = _checkpoint(out, job, overwrite, bool(resuming))
        if resuming and resume is None:
            raise DgtdInputError(f"{out} has no checkpoint to resume from; start the run with --checkpoint-every K")
        if resume is None:
            remove_logs(out)
        # (afresh, and also resumed: an extension's -T is what --resume goes on to, should it be cut off)
        atomic_write(out / CONFIG, config_toml(job.record, output).encode())
    except BaseException:
        owner.__exit__(None, None, None)
        raise
    held.append(owner)
    return resume


def config_toml(record: dict, output: dict) -> str:
    """config.toml of a learning run: the options it was given (its record, less what is derived from its files),
    and the ``output`` settings a resumed run keeps (`OUTPUT`: --checkpoint-every, --log), under [learn]."""
    import tomli_w

    table = {k: v for k, v in record.items() if v is not None and not k.endswith("_sha256")}
    table |= {k: v for k, v in output.items() if k in OUTPUT and v}
    return (
        "# dgtd learn: the options of this learning run; `dgtd learn --resume DIR` continues it from its last "
        "checkpoint\n" + tomli_w.dumps({"learn": table})
    )


def _checkpoint(out: Path, job, overwrite: bool, resuming: bool) -> dict | None:
    """The snapshot to resume from: the same command's checkpoint in ``out``, or, ``resuming`` with a larger -T, the
    state a finished run kept at its end (`dgtd.run.extend.extension`); another run's is refused (unless --overwrite,
    which starts afresh), and a finished run's, the same command again, is started afresh."""
    import json

    from dgtd.run.checkpoint import load_checkpoint
    from dgtd.run.extend import extension
    from dgtd.run.results import first_difference

    path = out / CHECKPOINT
    if not path.exists() or overwrite:
        return None
    saved, there = load_checkpoint(path)
    there, record = _steps(there or {}), _steps(json.loads(json.dumps(job.record)))  # (as the checkpoint holds it)
    if saved["k"] == there["iterations"] and (out / "summary.json").exists():  # a finished run's state at its end
        if not resuming:
            return None
        extends = extension(out, there, record, "learning run", blocker=lambda a, b: _warmup_blocker(job, a, b))
        return saved if extends is not None else None
    if diff := first_difference(there, record):
        raise DgtdInputError(
            f"{out} holds the checkpoint of another learning run ({diff}); choose another --out, or pass --overwrite"
        )
    return saved


def _warmup_blocker(job, T1: int, T2: int) -> str:
    """Why a learning run of T1 steps cannot go on to T2 ('' where it can): the actor's steps over the first T1
    would have been others in a run of T2 (its warm-up, a tenth of the run up to 2 000 steps, would be longer)."""
    import numpy as np

    if np.array_equal(job.actor.steps(0, T1), job.actor.steps(0, T1, T2)):
        return ""
    return (
        f"the actor holds still for a tenth of the run up to 2 000 steps (--actor-warmup), {job.actor.held_for(T1):,} "
        f"steps in this run and {job.actor.held_for(T2):,} in one of {T2:,}; a run of 20 000 steps or more extends"
    )


def _ended_at(resume: dict) -> int:
    """The last checkpoint step a snapshot kept (a finished run's end, where it is extended)."""
    steps = resume.get("steps")
    return int(steps[-1]) if steps is not None and len(steps) else int(resume["k"])


def _timescales(job) -> None:
    """The header's note where the actor's step is the larger after its warm-up (`dgtd.algorithms.actor.timescales`)."""
    from dgtd.algorithms.actor import timescales

    if job.chen is not None:  # (one actor step an iteration, after its critic: its own timescales)
        return
    said = timescales(job.actor, job.critic, job.settings.iterations)
    if said:
        click.echo(f"note: {said}", err=True)


def _actors(s) -> str:
    """The learners, and how networked ones know the team's reward."""
    if s.actor != "networked" or s.values != "state":
        return f"{s.actor} actors"
    how = "Zhang et al.'s regression" if s.team_reward == "regression" else "their neighbourhood's estimate"
    return f"networked actors (the team's reward by {how})"


def _critics_of(objective: str, gamma: float) -> str:
    """A simulator's critics in words: its return is the team's mean reward a step whatever the objective."""
    return "differential (average objective)" if objective == "average" else f"discounted at gamma {gamma:g}"


def _objective(objective: str, gamma: float) -> str:
    """The objective in words, as the header says it."""
    if objective == "average":
        return "the long-run average team reward (differential critics)"
    return f"the discounted team return at gamma {gamma:g} from the start, normalised by 1 - gamma"


def _actions(actions: tuple) -> str:
    return f"{actions[0]} actions each" if len(set(actions)) == 1 else f"actions {' x '.join(map(str, actions))}"


def _report(result, job) -> None:
    """The last numbers, in words: the exact return beside J* (a model's) or the estimated returns (a simulator's);
    the seeds that diverged, where any did."""
    import numpy as np

    from dgtd.run.learn import diverged

    gone = [(b, k) for b, k in enumerate(diverged(result)) if k is not None]
    if gone:
        stopped = result.info.get("stopped_at")
        click.echo(
            f"note: seed(s) {', '.join(f'{b} (by step {k:,})' for b, k in gone)} diverged: their critics or actors "
            "left the finite numbers, and their metrics are NaN from then on"
            + (f"; every seed had, so the run stopped at step {stopped:,}" if stopped is not None else "")
            + "; a smaller --alpha0 or --actor-step keeps them",
            err=True,
        )

    if job.env is not None:
        first, last = result.metrics["return"][0], result.metrics["return"][-1]
        click.echo(
            f"team's mean reward a step (estimated from the run's own steps), first checkpoint -> last, per seed: "
            f"{', '.join(f'{a:.4g} -> {b:.4g}' for a, b in zip(first, last))}"
        )
        episodes = result.metrics["episode_return"]
        if np.isfinite(episodes).any():  # (an episodic simulator: what shows learning there)
            click.echo(
                "team's mean return an episode (over the episodes ended since the last checkpoint), first -> last, "
                f"per seed: {', '.join(f'{a:.4g} -> {b:.4g}' for a, b in zip(episodes[0], episodes[-1]))}"
            )
        return
    last = result.metrics["return"][-1]
    best = "" if result.return_best is None else f" of the best joint policy's J* = {result.return_best:.4g}"
    kind = "average" if result.info.get("objective", "average") == "average" else "discounted"
    click.echo(f"exact return J of the last policies ({kind}): {', '.join(f'{x:.4g}' for x in last)} (per seed){best}")
    if np.isfinite(result.metrics["best_probability"][-1]).all():
        p = result.metrics["best_probability"][-1]
        click.echo(f"least probability any agent puts on the team's best action in any state: {np.min(p):.3f}")
    worst = np.max(result.metrics["critic_error"][-1])
    click.echo(f"critics' error against their exact fixed point under the last policies (relative), worst seed: "
               f"{worst:.3g}")  # fmt: skip


COMPARED = ("dgtd", "consensus-td0", "consensus-tdrc", "td-tracking")  # the networked critics compared by default


def compare_learners(task, algorithms, seeds, out, progress, plots, overwrite, given: dict) -> None:
    """`dgtd compare TASK` (or `--learn --problem FILE`): networked learners with each critic of ``algorithms``
    (default `COMPARED`), independent and centralised ones (DGTD critic), on the same keyed numbers; metrics.csv,
    summary.json, learners.png and a table that says which reached the highest exact return."""
    from dataclasses import replace

    from tqdm import tqdm

    from dgtd.algorithms import make_algorithm
    from dgtd.errors import DgtdInputError
    from dgtd.learning import CRITIC_STEPS, ENV_CRITIC_STEPS, resolve_learning
    from dgtd.run.atomic import atomic_write, atomic_write_json
    from dgtd.run.learn import DISTRIBUTED, metrics_csv
    from dgtd.run.owner import Owner

    job = resolve_learning(task, {**given, "seeds": seeds})
    names = tuple(a.strip() for a in algorithms.split(",")) if algorithms else COMPARED
    bad = [n for n in names if n not in DISTRIBUTED]
    if bad:
        raise DgtdInputError(
            f"learners' critics are distributed methods ({', '.join(DISTRIBUTED)}); got {', '.join(bad)}"
        )
    runs = [("networked", n) for n in names] + [("independent", "dgtd"), ("centralised", "dgtd")]
    name, n_agents, run = _learner_runs(job)
    out = Path(out) if out else Path("runs") / f"compare-learners-{name}"
    s = job.settings
    click.echo(f"{name}: {n_agents} agents; {job.network.describe()}; {job.channel.describe()}")
    click.echo(f"{', '.join(f'{a} ({n} critic)' for a, n in runs)}: {s.iterations:,} steps x {s.seeds} seed(s) each")
    results = {}
    with Owner(out, "learning run", overwrite):
        bar = tqdm(total=s.iterations * len(runs), disable=not progress, file=sys.stderr, unit="it", unit_scale=True)
        try:
            for actor, critic_name in runs:
                critic = make_algorithm(critic_name, **(CRITIC_STEPS if job.env is None else ENV_CRITIC_STEPS))
                results[f"{actor}/{critic_name}"] = run(
                    job.network, critic, job.actor, replace(s, actor=actor), job.channel, progress=bar.update
                )
        finally:
            bar.close()
        atomic_write(out / "metrics.csv", metrics_csv(results, "learners"))
        atomic_write_json(out / "summary.json", _compared(results, job))
        written = ["metrics.csv", "summary.json"]
        if plots:
            from dgtd.plots.learning import learners_figure

            written.append(learners_figure(out, results, name))
    click.echo(_learners_table(results))
    click.echo(f"wrote {out}/{', '.join(written)}")


def _learner_runs(job) -> tuple:
    """(the task's name, its agents, run(network, critic, actor, settings, channel, progress) -> `LearnResult`):
    `dgtd.run.learn.learn` on the model or the simulator."""
    from functools import partial

    from dgtd.run.learn import learn

    problem = job.env if job.env is not None else job.mdp
    return problem.name, problem.n_agents, partial(learn, problem)


def _compared(results: dict, job) -> dict:
    import numpy as np

    out = {
        "task": _learner_runs(job)[0],
        "config": job.record,
        "objective": job.settings.objective,
        "return_best": next(iter(results.values())).return_best,
    }
    for label, r in results.items():
        J = r.metrics["return"][-1]
        out[label] = {
            "return_last": {"median": float(np.median(J)), "min": float(J.min()), "max": float(J.max())},
            "failed_seeds": int(_failed(r).sum()),
            "best_probability_last": r.metrics["best_probability"][-1].tolist(),
            "critic_error_last": r.metrics["critic_error"][-1].tolist(),
            "messages": r.messages.tolist(),
            "bits": r.bits.tolist(),
            "seconds": r.seconds,
        }
    return out


def _failed(result):
    """Each seed's failure (B,): its return not finite, or on a model its critics' error (a diverged run); a
    simulator measures no critic error."""
    import numpy as np

    bad = ~np.isfinite(result.metrics["return"][-1])
    if not result.info.get("estimated", False):
        bad |= ~np.isfinite(result.metrics["critic_error"][-1])
    return bad


def _learners_table(results: dict) -> str:
    """One line per learners, each number at the end of the run: the return J (median over seeds, and its range),
    the probability on the team's best action (median, and the worst seed's), the critics' error (median), what was
    sent, and the seeds that failed (J or the critics' error not finite: a diverged run); then the highest median
    return among the learners without a failed seed, and those tied with it (their seeds' ranges overlap)."""
    import numpy as np

    rows = [
        f"{'learners':<28}{'J last':>10}{'seeds':>22}{'p(best) (worst)':>17}{'critic err':>12}{'messages':>11}"
        f"{'bits':>11}{'failed':>8}"
    ]
    failed = {}
    for label, r in results.items():
        J = r.metrics["return"][-1]
        least, error = r.metrics["best_probability"][-1], r.metrics["critic_error"][-1]
        failed[label] = int(_failed(r).sum())
        shown = f"{np.median(least):.3f} ({np.min(least):.3f})" if np.isfinite(least).all() else "-"
        err = f"{np.nanmedian(error):.3g}" if np.isfinite(error).any() else "-"  # (a simulator measures none)
        rows.append(
            f"{label:<28}{np.nanmedian(J):>10.4g}{f'{np.nanmin(J):.4g} to {np.nanmax(J):.4g}':>22}{shown:>17}"
            f"{err:>12}{np.max(r.messages):>11.3g}{np.max(r.bits):>11.3g}{f'{failed[label]} of {len(J)}':>8}"
        )
    first = next(iter(results.values()))
    estimated = first.info.get("estimated", False)
    objective = first.info.get("objective", "average")
    rows.append(
        "each number: at the end of the run, median over seeds; J is "
        + (
            "the team's mean reward a step since the last checkpoint, estimated from the run's own rewards (no model)"
            if estimated
            else "the exact long-run average team reward of the policies"
            if objective == "average"
            else "the exact discounted team return of the policies from the start, times 1 - gamma"
        )
    )
    whole = [label for label in results if not failed[label]]
    if not whole:
        return "\n".join([*rows, "every learners had a failed seed: none is named the highest"])
    median = {label: float(np.median(results[label].metrics["return"][-1])) for label in whole}
    best = max(whole, key=median.__getitem__)
    J = results[best].metrics["return"][-1]
    tied = [label for label in whole if label != best and results[label].metrics["return"][-1].max() >= J.min()]
    of = "" if first.return_best is None else f" of J* = {first.return_best:.4g}"
    line = f"highest return: {best}, {median[best]:.4g}{of} (seeds {J.min():.4g} to {J.max():.4g})"
    if tied:
        line += f"; tied with it (their seeds' ranges overlap): {', '.join(tied)}"
    return "\n".join([*rows, line])


for _param in learn.params:
    _param.help = LEARN_HELP.get(_param.name or "", getattr(_param, "help", None))
