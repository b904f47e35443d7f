"""Every `pimbot` command as a frozen dataclass: its fields are the command's options.

The field docstrings are the `--help` text; tyro adds each field's default and,
for `Literal` fields, the allowed values. The registry names (environments,
learners, attacks, defenses) are `Literal`s built after the plugins have
loaded, so `--help` lists a plugin's names like the built-ins'.

This module does not use `from __future__ import annotations`: the classes are
made inside `build`, and their annotations must be real types that close over
its arguments.
"""

import dataclasses
from typing import Annotated, Literal

import tyro

from pimbot.contracts.params import check_int, check_number
from pimbot.envs.core import InvalidParameter

PAIRS = "pimbot:name=value"
"""Marks a field holding `name=value` strings; a --config file may give it a table."""


def _pairs_option(metavar: str = "NAME=VALUE", aliases: tuple[str, ...] = ()):
    return Annotated[
        tuple[str, ...],
        tyro.conf.UseAppendAction,
        tyro.conf.arg(metavar=metavar, aliases=aliases or None),
        PAIRS,
    ]


_PositionalPairs = Annotated[
    tuple[str, ...], tyro.conf.Positional, tyro.conf.arg(metavar="NAME=VALUE"), PAIRS
]
_Repeated = Annotated[tuple[str, ...], tyro.conf.UseAppendAction]


@dataclasses.dataclass(frozen=True)
class Choices:
    """The allowed names of each registry and of the fixed option sets."""

    env_ids: tuple[str, ...]
    learners: tuple[str, ...]
    attacks: tuple[str, ...]
    defenses: tuple[str, ...]
    controllers: tuple[str, ...]
    backends: tuple[str, ...]
    trackers: tuple[str, ...]
    renderers: tuple[str, ...]


@dataclasses.dataclass(frozen=True, kw_only=True)
class Command:
    """Options every command takes."""

    plugin: Annotated[_Repeated, tyro.conf.arg(metavar="MODULE")] = ()
    """Load a plugin first: a module name or a .py file (repeatable)."""
    config: Annotated[str | None, tyro.conf.arg(metavar="FILE")] = None
    """Options from a TOML/YAML file (keys: option names); the command line overrides it."""

    def __post_init__(self) -> None:
        for name, low in self.int_bounds().items():
            value = getattr(self, name)
            if value is not None and value is not tyro.MISSING:
                check_int(name, value, low)
        for name in self.positive_numbers():
            value = getattr(self, name)
            if value is not None and value is not tyro.MISSING:
                check_number(name, value, 0, strict_low=True)

    def int_bounds(self) -> dict[str, int]:
        """Integer options and their lowest allowed value."""
        return {}

    def positive_numbers(self) -> tuple[str, ...]:
        """Number options that must be finite and > 0."""
        return ()


def build(choices: Choices) -> dict:
    """The command tree: name -> command class, or name -> {"": what the group is for,
    subcommand: class, ...}."""
    EnvId = Literal[choices.env_ids]
    Learner = Literal[choices.learners]
    AttackName = Literal[choices.attacks]
    DefenseName = Literal[choices.defenses]

    @dataclasses.dataclass(frozen=True, kw_only=True)
    class Logging:
        log: Annotated[
            _Repeated,
            tyro.conf.arg(
                metavar="BACKEND",
                help="Stream every metrics row and the config to a tracker: "
                f"{', '.join(choices.trackers)} (repeatable or comma-separated; "
                "pip install 'pimbot[tracking]').",
            ),
        ] = ()

    @dataclasses.dataclass(frozen=True, kw_only=True)
    class Train(Logging, Command):
        """Train one learner on one environment, S seeds (rerun the same command to resume)."""

        env_id: tyro.conf.Positional[EnvId]
        """Environment id (see `pimbot envs`)."""
        env_params: _PositionalPairs = ()
        """Environment parameters, e.g. n_agents=4 min_at_lever=2 (see `pimbot envs`)."""
        learner: Learner = "lio"
        """Learner (see `pimbot learners` for its hyperparameters)."""
        hp: _pairs_option() = ()
        """Override a learner hyperparameter (repeatable), e.g. --hp lr_policy=1e-3."""
        seeds: int = 10
        """Number of independent seeds S (≥ 1)."""
        first_seed: int = 0
        """First seed value (≥ 0); the seeds are first_seed … first_seed + S − 1."""
        iterations: int = 50_000
        """Training iterations per seed (≥ 1, a multiple of the evaluation period)."""
        eval_period: int | None = None
        """Iterations between evaluations (≥ 1); None: the environment's (ER 100, others 1000)."""
        eval_episodes: int | None = None
        """Episodes per evaluation (≥ 1); None: 10."""
        attack: AttackName | None = None
        """Manipulate one agent (see `pimbot attacks`); None: a clean run."""
        attack_param: _pairs_option(aliases=("--ap",)) = ()
        """Attack parameter (repeatable), e.g. --ap adversary=1 --ap mode=stealthy."""
        defense: Annotated[tuple[DefenseName, ...], tyro.conf.UseAppendAction] = ()
        """Training-time defense of the honest agents (repeatable; see `pimbot defenses`)."""
        defense_param: _pairs_option("[DEFENSE.]NAME=VALUE", aliases=("--dp",)) = ()
        """Defense parameter (repeatable), e.g. --dp health_monitor.patience=20."""
        audit_log: Annotated[str | None, tyro.conf.arg(metavar="PATH")] = None
        """Append a keyed (HMAC-SHA256) audit log of the run to this file."""
        audit_key: Annotated[str | None, tyro.conf.arg(metavar="FILE")] = None
        """Audit log key file, not in the log's directory (made 0600 if missing); None: default."""
        out: Annotated[str | None, tyro.conf.arg(metavar="DIR")] = None
        """Run directory (created; rerun to resume). Required unless --from is given."""
        from_run: Annotated[str | None, tyro.conf.arg(name="from", metavar="RUN_DIR")] = None
        """Rerun a saved run: its config gives every default; without --out, continue it."""
        restart: bool = False
        """Start the run in --out over: remove what a previous run wrote there first."""
        chunk_iterations: int = 2000
        """Iterations between checkpoints (≥ 1; whole eval periods; results unchanged)."""
        quiet: bool = False
        """No progress display."""

        def int_bounds(self) -> dict[str, int]:
            return {
                "seeds": 1,
                "first_seed": 0,
                "iterations": 1,
                "eval_period": 1,
                "eval_episodes": 1,
                "chunk_iterations": 1,
            }

    @dataclasses.dataclass(frozen=True, kw_only=True)
    class Table(Command):
        """Markdown table of finished runs' final metrics."""

        run_dirs: Annotated[tuple[str, ...], tyro.conf.Positional, tyro.conf.arg(metavar="RUN")]
        """Run directories."""

    @dataclasses.dataclass(frozen=True, kw_only=True)
    class Plot(Command):
        """Learning curves of runs (mean ± 95 % CI) as PNG (an SVG is written beside it)."""

        run_dirs: Annotated[tuple[str, ...], tyro.conf.Positional, tyro.conf.arg(metavar="RUN")]
        """Run directories."""
        out: Annotated[str, tyro.conf.arg(metavar="FILE.png")]
        """PNG file to write."""

    @dataclasses.dataclass(frozen=True, kw_only=True)
    class Profile(Command):
        """Decision latency, update cost and hardware traces of a controller (benign vs ADMO)."""

        env: EnvId
        """Environment id (see `pimbot envs`)."""
        env_params: _PositionalPairs = ()
        """Environment parameters, e.g. n_agents=4 min_at_lever=2."""
        controller: Literal[choices.controllers] = "benign"
        """benign: plain LIO; admo: ADMO on agent 0; admo_code: the published code's ADMO."""
        duration: float = 20.0
        """Steady-state seconds per controller (> 0)."""
        hidden: tuple[int, ...] = (256, 128)
        """Hidden widths of the policy and incentive MLPs (each ≥ 1)."""
        action_repeat: int = 2
        """Environment steps per decision (≥ 1)."""
        update_every: tuple[int, ...] = (2, 10, 100)
        """Decisions per learner update, one interleaved segment each (each ≥ 1)."""
        pin_cpu: Annotated[str | None, tyro.conf.arg(metavar="CPUS")] = None
        """Pin the process to these CPUs, e.g. 0,2-3."""
        sample_hz: float = 1.0
        """Sensor sampling rate in Hz (> 0)."""
        seed: int = 0
        """Root PRNG seed (≥ 0)."""
        paired: bool = False
        """Benign then ADMO, everything else identical."""
        truncate_idle_gpu: bool = False
        """Cut long zero-GPU stretches in the figure."""
        out: Annotated[str, tyro.conf.arg(metavar="DIR")]
        """Run directory (created)."""

        def int_bounds(self) -> dict[str, int]:
            return {"action_repeat": 1, "seed": 0}

        def __post_init__(self) -> None:
            super().__post_init__()
            for name in ("hidden", "update_every"):
                values = getattr(self, name)
                if values is not tyro.MISSING:
                    if not values:
                        raise InvalidParameter(f"{name}: give at least one value")
                    for i, value in enumerate(values):
                        check_int(f"{name}[{i}]", value, 1)

        def positive_numbers(self) -> tuple[str, ...]:
            return ("duration", "sample_hz")

    @dataclasses.dataclass(frozen=True, kw_only=True)
    class Suite(Logging, Command):
        only: Annotated[_Repeated, tyro.conf.arg(metavar="PATTERN")] = ()
        """Run only jobs whose <group>/<setting> name matches (repeatable; wildcards)."""
        backend: Literal[choices.backends] = "local"
        """local: a process pool on this machine; ray: one Ray task per job."""
        workers: int = 0
        """Jobs at a time (≥ 0); 0: one per CPU core locally, all at once on Ray."""
        devices_per_job: int = 0
        """CPU cores each job shards its seeds over (≥ 0); 0: cores / workers."""
        ray_address: Annotated[str | None, tyro.conf.arg(metavar="ADDRESS")] = None
        """Ray cluster to join: auto or HOST:PORT; None: start a local one (--backend ray)."""
        list: bool = False
        """Print the plan (every job and its status) and exit."""
        quiet: bool = False
        """No progress display."""
        out: Annotated[str, tyro.conf.arg(metavar="DIR")]
        """Suite directory (rerun the same command to resume)."""

        def int_bounds(self) -> dict[str, int]:
            return {"workers": 0, "devices_per_job": 0}

    @dataclasses.dataclass(frozen=True, kw_only=True)
    class Reproduce(Suite):
        """Run the paper's whole experiment suite into one directory (resumable)."""

        quick: bool = False
        """3 seeds and a fifth of the iterations: every setting and figure, in minutes."""

    @dataclasses.dataclass(frozen=True, kw_only=True)
    class Sweep(Suite):
        """Run a grid of envs × learners × attacks × defenses from a TOML file (resumable)."""

        grid: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="GRID.toml")]
        """Grid file (TOML; see docs/examples/grid.toml)."""

    @dataclasses.dataclass(frozen=True, kw_only=True)
    class Report(Command):
        """report.md and report.html (figures, tables, claims) from a suite directory."""

        suite_dir: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="SUITE_DIR")]
        """Directory written by `pimbot reproduce` or `pimbot sweep`."""
        out: Annotated[str | None, tyro.conf.arg(metavar="DIR")] = None
        """Where to write; None: SUITE_DIR."""

    @dataclasses.dataclass(frozen=True, kw_only=True)
    class Envs(Command):
        """List the environments, their parameters (defaults, meaning) and learner defaults."""

    @dataclasses.dataclass(frozen=True, kw_only=True)
    class Learners(Command):
        """List the learners, their hyperparameters (defaults, meaning) and hook points."""

    @dataclasses.dataclass(frozen=True, kw_only=True)
    class Attacks(Command):
        """List the attacks, their parameters (defaults, meaning) and hook points."""

    @dataclasses.dataclass(frozen=True, kw_only=True)
    class Defenses(Command):
        """List the defenses and their parameters (defaults, meaning)."""

    @dataclasses.dataclass(frozen=True, kw_only=True)
    class AuditVerify(Command):
        """Verify a keyed audit log and its signed head; names the first bad record."""

        log: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="LOG")]
        """The JSONL audit log."""
        head: str | None = None
        """A head MAC printed when the log was written; the log must contain it."""
        audit_key: Annotated[str | None, tyro.conf.arg(metavar="FILE")] = None
        """The log's key file; None: $PIMBOT_AUDIT_KEY_FILE, else ~/.config/pimbot/audit.key."""

    @dataclasses.dataclass(frozen=True, kw_only=True)
    class RobotRun(Command):
        run_dir: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="RUN_DIR")]
        """A pimbot run directory of escape_room-v0."""
        nominal_room: bool = False
        """The fixed room instead of random layouts."""

    @dataclasses.dataclass(frozen=True, kw_only=True)
    class RobotEval(RobotRun):
        """Physics success next to abstract success, per seed, on TurtleBot3-sized robots."""

        episodes: int = 10
        """Episodes per seed (≥ 1)."""
        rosbag: Annotated[str | None, tyro.conf.arg(metavar="DIR")] = None
        """Write the first seed's first episode as a ROS 2 bag (pip install 'pimbot[rosbag]')."""
        json: Annotated[str | None, tyro.conf.arg(metavar="FILE")] = None
        """Write the results as JSON to this file."""
        physics: Annotated[tuple[str, ...], tyro.conf.arg(metavar="NAME=VALUE"), PAIRS] = ()
        """Physics settings, e.g. actuation_noise=0.2 decision_time_limit=15."""

        def int_bounds(self) -> dict[str, int]:
            return {"episodes": 1}

    @dataclasses.dataclass(frozen=True, kw_only=True)
    class RobotRender(RobotRun):
        """Top-down video of one physics episode (.gif, or .mp4 with ffmpeg)."""

        out: Annotated[str, tyro.conf.arg(metavar="VIDEO")]
        """Video file: .gif, or .mp4 (needs ffmpeg)."""
        seed_index: int = 0
        """Which seed of the run (≥ 0)."""
        episode: int = 0
        """Which episode of that seed (≥ 0)."""
        renderer: Literal[choices.renderers] = "auto"
        """auto: MuJoCo if OpenGL works here, else matplotlib."""
        frame: Annotated[str | None, tyro.conf.arg(metavar="FRAME.png")] = None
        """Also write the episode's last frame as this PNG."""

        def int_bounds(self) -> dict[str, int]:
            return {"seed_index": 0, "episode": 0}

    return {
        "train": Train,
        "sweep": Sweep,
        "reproduce": Reproduce,
        "report": Report,
        "table": Table,
        "plot": Plot,
        "profile": Profile,
        "envs": Envs,
        "learners": Learners,
        "attacks": Attacks,
        "defenses": Defenses,
        "audit": {"": "Tamper-evident audit logs.", "verify": AuditVerify},
        "robot": {
            "": "Trained Escape Room policies on TurtleBot3-sized robots in MuJoCo.",
            "eval": RobotEval,
            "render": RobotRender,
        },
    }


def summary(node) -> str:
    """The first line of a command's docstring; a group's own line and its subcommands."""
    if isinstance(node, dict):
        return f"{node['']} ({', '.join(n for n in node if n)})"
    return ((node.__doc__ or "").strip().splitlines() or [""])[0]
