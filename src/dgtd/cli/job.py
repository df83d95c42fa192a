"""One run of an experiment into its results directory, with periodic checkpoints and exact resume.

The directory gets ``config.toml`` (the fully resolved experiment: ``dgtd run DIR/config.toml`` reproduces
the run) before the run starts, ``checkpoint.npz`` every ``checkpoint_every`` iterations while it runs and at its
end, and the results (`dgtd.run.results.write_results`) when it ends. The last checkpoint stays, so that
``--resume DIR -T LARGER`` extends the finished run (`dgtd.run.extend`).
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from dgtd.config import (
    PROBLEM_FIELDS,
    RunConfig,
    input_files,
    make_source,
    resolve,
    scenario_of,
    spec_record,
)
from dgtd.errors import DgtdInputError
from dgtd.experiments import Experiment, absolute_paths, to_toml
from dgtd.run import runtime
from dgtd.run.checkpoint import drop_shards, load_checkpoint, remove_checkpoint
from dgtd.run.extend import extension, other_length, without_state
from dgtd.run.logs import remove_logs
from dgtd.run.owner import Owner
from dgtd.run.results import MeasuredSoFar, atomic_write, first_difference, refuse_other_results, saved_config
from dgtd.run.settings import tail_blocker

CONFIG, CHECKPOINT, SCENARIO_ARRAYS = "config.toml", "checkpoint.npz", "scenario.npz"
HEADER = "The fully resolved config of a dgtd run: `dgtd run THIS_FILE` reproduces it exactly."


@dataclass
class PreparedRun:
    """A resolved run and where it goes: the library objects, the resolved config and, when resuming, the snapshot."""

    config: RunConfig
    problem: Any
    network: Any
    algorithm: Any
    sampling: Any
    settings: Any
    resolved: RunConfig  # every field given its value (`dgtd.config.resolve`)
    out: Path
    record: dict
    channel: Any  # the links' model, built once (`dgtd.config.resolve`)
    snapshot: dict | None = None
    finished: bool = False
    extends: int | None = None  # the step a finished run extended to a larger -T ended at
    source: Any = None
    report_text: str = ""
    owner: Any = None  # the lock on ``out`` (`dgtd.run.owner.Owner`), held until `release`

    def release(self) -> None:
        """Let the results directory go: another command may write into it now."""
        if self.owner is not None:
            self.owner.release()

    @property
    def config_toml(self) -> str:
        output = replace(self.config.output, out=str(self.out), resume=False)
        return to_toml(Experiment(replace(self.resolved, output=output)), HEADER)

    def run(self, progress: bool | None = None):
        """Run (or continue) the loop, saving a checkpoint every ``checkpoint_every`` iterations."""
        from tqdm import tqdm

        from dgtd.run.loop import run as run_loop

        show = self.config.output.progress if progress is None else progress
        done = 0 if self.snapshot is None else int(self.snapshot["k"])
        bars = []

        def start_bar(kernel_seconds: float) -> None:
            """The kernels are loaded (or compiled): only now does the bar start, so that its rate is the run's."""
            if kernel_seconds > 1.0 and show:
                print(
                    f"compiled the {self.settings.backend} kernels in {kernel_seconds:.1f} s (once per machine: "
                    "later runs load them from the cache)",
                    file=sys.stderr,
                    flush=True,
                )
            bars.append(
                tqdm(
                    total=self.settings.iterations,
                    initial=done,
                    unit="it",
                    unit_scale=True,
                    disable=not show,
                    file=sys.stderr,
                    mininterval=0.5,
                )
            )

        def advance(n: int) -> None:
            bars[0].update(n)

        every = self.config.output.checkpoint_every
        ckpt = self.out / CHECKPOINT
        self.source = make_source(self.resolved, self.settings)  # None: samples from the model; else a simulator's
        runtime.watch(self.algorithm, every)
        # one copy of the run's files: the writing process's, or where the agents are spread, a shard of it a rank
        saver = runtime.checkpoint_saver(self.algorithm, ckpt, self.record)
        measured = MeasuredSoFar(self.out, self.algorithm.name) if runtime.writes() else None
        try:
            return run_loop(
                self.problem,
                self.network,
                self.algorithm,
                self.sampling,
                self.settings,
                progress=advance,
                source=self.source,
                checkpoint_every=every,
                on_checkpoint=saver,
                resume=self.snapshot,
                kernel_ready=start_bar,
                channel=self.channel,
                on_measured=measured,
            )
        except KeyboardInterrupt:  # what was measured is kept (metrics.csv of the checkpoints so far)
            if measured is not None:
                measured.write()
            raise
        finally:
            for bar in bars:
                bar.close()

    def save(self, result, plots: bool | None = None) -> list[str]:
        """Write the results, drop the checkpoint (kept with --checkpoint-every: the state at T, which a larger -T
        extends), then draw the figures; returns the names
        written."""
        from dgtd.run.results import npz_bytes, write_results

        plots = self.config.output.plots if plots is None else plots
        # where every agent's rows stay on their ranks, no scenario report: it takes them all
        sc = scenario_of(self.resolved) if result.rows is None else None
        extra = None
        if sc is not None and sc.report is not None:  # a scenario's own numbers (e.g. the robots' map correlations)
            extra, self.report_text = sc.report(result, self.source)
        also = {}
        if sc is not None and hasattr(sc.report, "arrays"):  # what the scenario's figures need, for `dgtd plot`
            also[SCENARIO_ARRAYS] = lambda: npz_bytes(sc.report.arrays(self.source))
        names = write_results(self.out, result, self.record, algorithm=self.algorithm.name, extra=extra, also=also)
        if not runtime.writes():  # a rank that wrote its agents' rows (`RunResult.rows`): rank 0 does the rest
            return names
        if self.config.output.log:
            from dgtd.run.logs import log_kinds, write_logs
            from dgtd.run.results import metrics_rows

            rows = metrics_rows(result, self.algorithm.name)
            names += write_logs(self.out, log_kinds(self.config.output.log), rows, self.record)
        if not self.config.output.checkpoint_every:  # (with it, the state at T is kept: a larger -T extends the run)
            remove_checkpoint(self.out / CHECKPOINT)
        if plots:
            try:
                names += self._figures(result, sc)
            except KeyboardInterrupt:
                raise FiguresInterrupted(self.out) from None
        return names

    def _figures(self, result, sc) -> list[str]:
        from dgtd.plots import plot_errors, plot_iterates, scenario_figures

        names = []
        if plot_iterates(result, self.out / "iterates.png", algorithm=self.algorithm.name):
            names.append("iterates.png")
        plot_errors(result, self.out / "errors.png")
        names.append("errors.png")
        if sc is not None and sc.report is not None:
            files = scenario_figures(sc.report, result, self.source, self.out)
            names += files
            if files:
                self.report_text += f"\nwrote {', '.join(files)}"
        return names


class FiguresInterrupted(KeyboardInterrupt):
    """Ctrl-C while the figures were drawn: the numbers are all written already, and the message says so."""

    def __init__(self, out):
        super().__init__(
            f"interrupted while drawing the figures: the results (summary.json, metrics.csv, "
            f"trajectory.npz) are complete in {out}; some figures are missing, and `dgtd plot {out}` "
            "draws them all again"
        )


def execute(config: RunConfig):
    """Run ``config`` as ``dgtd run`` does, into its output directory (config.toml, the results, and figures if
    ``config.output.plots``), and return the `dgtd.run.loop.RunResult`. With ``output.resume`` it continues the run
    saved there; a finished one is read back (`dgtd.run.results.read_results`)."""
    job = prepare(config)
    try:
        if job.finished:
            from dgtd.run.results import read_results

            return read_results(job.out)
        result = job.run()
        if runtime.writes() or result.rows is not None:  # (spread rows: every rank writes its agents')
            job.save(result)
        return result
    finally:
        job.release()


def prepare(exp: Experiment | RunConfig) -> PreparedRun:
    """Resolve a run's config, check a resume against its checkpoint, and write config.toml."""
    if isinstance(exp, Experiment):
        if exp.grid:
            raise DgtdInputError("this experiment has a [grid]: run it with `dgtd sweep FILE`")
        exp = exp.config
    config = exp
    if all(getattr(config.problem, name) is None for name in PROBLEM_FIELDS):
        raise DgtdInputError(
            "name a scenario (dgtd scenarios lists them), give --problem FILE.npz, --env "
            "module:make_env, --data FILE, or an experiment file"
        )
    run_length: Any = config.run  # (a dataclass made from RunSettings' fields)
    if runtime.in_job() and run_length.backend is None and run_length.asynchronous:  # ranks that do not wait run
        config = replace(config, run=replace(config.run, backend="numpy"))  # the reference (`runtime.check_supported`)
    problem, network, algorithm, sampling, settings, resolved, channel = resolve(absolute_paths(config))
    out = Path(config.output.out) if config.output.out else Path("runs") / problem.name
    try:
        out = out.resolve()
    except (RuntimeError, OSError) as e:  # a loop of symbolic links on the way (RuntimeError before Python 3.13)
        raise DgtdInputError(f"--out {out} passes through a symbolic link that loops ({e}); choose another") from None
    record = json.loads(json.dumps(spec_record(resolved)))
    runtime.check_supported(  # what the ranks cannot run, said before anything starts
        algorithm, channel, problem.n_agents, settings.backend, settings.asynchronous
    )
    pieces = (config, problem, network, algorithm, sampling, settings, resolved, out, record, channel)

    def claim() -> PreparedRun:  # the writing process claims the directory and writes config.toml
        run = PreparedRun(*pieces, owner=Owner(out, "run", config.output.overwrite))
        try:
            return _claim(run, config.output, out, record)
        except BaseException:
            run.release()
            raise

    def follow() -> PreparedRun:  # the other ranks read what they resume from, as the writing one found it
        run = PreparedRun(*pieces)
        if (out / CHECKPOINT).exists() and (config.output.resume or not config.output.overwrite):
            run.snapshot = load_checkpoint(out / CHECKPOINT)[0]  # (it has not cleared it)
        run.finished = config.output.resume and (run.snapshot is None or run.snapshot["k"] == record["iterations"])
        return run

    return runtime.claimed(claim, follow)


def _claim(run: PreparedRun, output, out: Path, record: dict) -> PreparedRun:
    """Check a resume against its checkpoint (asked for, or the same command again on a run that was cut off), or
    clear the previous run and write config.toml."""
    ckpt, summary = out / CHECKPOINT, out / "summary.json"
    if output.resume and not ckpt.exists():
        if summary.exists():
            without_state(out, saved_config(summary), record, "run", f"dgtd run {out / CONFIG}")
            run.finished = True
            return run
        raise DgtdInputError(f"{out} has no checkpoint to resume from; start the run with --checkpoint-every K")
    snapshot, saved = load_checkpoint(ckpt) if ckpt.exists() and (output.resume or not output.overwrite) else (None, {})
    ended = snapshot is not None and summary.exists() and snapshot["k"] == saved.get("iterations")
    if output.resume and ended and snapshot is not None:  # a finished run that kept its last state: extended, or done
        return _extended(run, out, snapshot, saved, record)
    if ended and not output.overwrite:
        other_length(out, saved, record, "run", "dgtd run")
    if output.resume or (snapshot is not None and not ended):
        diff = first_difference(saved, record)
        _refuse_changed_files(run, out, saved, record)
        if diff and output.resume:
            raise DgtdInputError(f"the checkpoint in {out} is of another config ({diff}); resume with {out / CONFIG}")
        if diff:
            raise DgtdInputError(
                f"{out} holds the checkpoint of another run ({diff}); continue it with `dgtd run --resume {out}`, "
                "choose another --out, or pass --overwrite to replace it"
            )
        run.snapshot = snapshot
    else:
        clear_previous_run(out, record, output.overwrite)
        atomic_write(out / CONFIG, run.config_toml.encode())
    return run


def _extended(run: PreparedRun, out: Path, snapshot: dict, saved: dict, record: dict) -> PreparedRun:
    """A finished run that kept its last state, asked to go on: extended to the larger -T ``record`` gives (its
    config.toml rewritten with it, so that --resume continues the extension if it is cut off), or finished."""
    _refuse_changed_files(run, out, saved, record)
    fraction = float(record["tail_fraction"])
    if extension(out, saved, record, "run", blocker=lambda a, b: tail_blocker(a, b, fraction)) is None:
        run.finished = True
        return run
    run.snapshot, run.extends = snapshot, int(snapshot["k"])
    atomic_write(out / CONFIG, run.config_toml.encode())
    return run


def _refuse_changed_files(run: PreparedRun, out: Path, saved: dict, record: dict) -> None:
    """Refuse to continue a checkpoint whose input files changed since it was written (their SHA-256)."""
    changed = [k for k in sorted(set(saved) | set(record)) if k.endswith("_sha256") and saved.get(k) != record.get(k)]
    if changed and all(k in saved and k in record for k in changed):  # the file, not what is derived from it
        role = changed[0].removesuffix("_sha256")
        raise DgtdInputError(
            f"the {role} file {input_files(run.config)[role]} changed since the checkpoint in {out} "
            "was written (its SHA-256 differs): put the file back as it was to continue the run, or pass "
            "--overwrite to start it afresh on the file as it is"
        )


# What `dgtd run` writes into its directory (its own figures and a scenario's: the patrol world's); another run's
# copies of them go before a new run writes. Nothing else in the directory is touched.
RUN_FILES = (
    SCENARIO_ARRAYS,
    "summary.json",
    "metrics.csv",
    "bands.csv",
    "trajectory.npz",
    "message_ages.csv",
    CHECKPOINT,
    "iterates.png",
    "errors.png",
    "maps.png",
    "reference.png",
    "snapshots.png",
    "patrol.gif",
    "curves.png",
    "values.png",
)


def clear_previous_run(out: Path, record: dict, overwrite: bool) -> None:
    """Refuse to write over the finished results of another configuration unless ``overwrite``; then remove the
    previous run's results, checkpoint and figures, so that the directory holds this run's files only."""
    if not overwrite:
        refuse_other_results(out, record, "run")
    for name in RUN_FILES:
        (out / name).unlink(missing_ok=True)
    remove_logs(out)
    drop_shards(out / CHECKPOINT)  # a spread run's other ranks' shards of its checkpoint
