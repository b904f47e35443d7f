"""Every `pimbot` command as a frozen dataclass: its fields are the command's options.

A command class is the command line, the configuration and the documentation at once (as
in CleanRL's single-file scripts, https://docs.cleanrl.dev/get-started/basic-usage/): tyro
reads the fields, their defaults and their docstrings into `--help`
(https://brentyi.github.io/tyro/), and `run` is what the command does. `COMMANDS` maps each
command path to its class; nothing else decides which command runs.

The module imports no JAX, so every `--help` answers at once. The names a registry holds
(environments, learners, attacks, defenses; plugins add to them) are therefore plain
strings here, marked `Registered`: `--help` points to the listing command, and the names
are checked against the registries after the plugins have loaded (`parsing.check_names`).
The fixed option sets (controllers, sweep backends, trackers, renderers) are `Literal`s,
so `--help` lists them; tests/test_cli.py checks them against the modules that use them.
"""

import dataclasses
from typing import Annotated, ClassVar, Literal

import tyro

from pimbot.cli.options import PAIRS, FromRun, Registered, Spelling
from pimbot.cli.robot import RENDERERS
from pimbot.contracts.params import check_number
from pimbot.errors import InvalidParameter, check_int
from pimbot.robot.rosbag import BAG_STORAGES, ROS_DISTROS

CONTROLLERS = ("benign", "admo", "admo_code")
"""`pimbot.profiling.CONTROLLERS` (that module imports JAX)."""
BACKENDS = ("local", "ray")
"""`pimbot.suites.sweep.BACKENDS` (that module imports JAX)."""
TRACKERS = ("tensorboard", "wandb", "mlflow")
"""`pimbot.training.tracking.BACKENDS` (that module imports JAX)."""


MAX_PROFILED_WIDTH = 2**16
"""The largest hidden layer (and update period) `pimbot profile` takes: 65 536 units already
make a controller of gigabytes; a larger number is a typo that would exhaust memory."""


def _option(metavar: str, *, name: str | None = None, aliases: tuple[str, ...] = ()) -> tuple:
    """Annotated metadata: tyro's spelling of an option, and the same for pimbot's messages."""
    return (
        tyro.conf.arg(metavar=metavar, name=name, aliases=aliases or None),
        Spelling(name, aliases),
    )


_Repeated = Annotated[tuple[str, ...], tyro.conf.UseAppendAction]
_Pairs = Annotated[tuple[str, ...], tyro.conf.UseAppendAction, PAIRS]
_PositionalPairs = Annotated[
    tuple[str, ...], tyro.conf.Positional, tyro.conf.arg(metavar="NAME=VALUE"), PAIRS
]
_Runs = Annotated[tuple[str, ...], tyro.conf.Positional, tyro.conf.arg(metavar="RUN")]
_EnvId = Annotated[str, tyro.conf.arg(metavar="ENV_ID"), Registered("envs")]
_Metrics = Annotated[_Repeated, tyro.conf.arg(metavar="NAME")]
"""Names of metrics.csv columns (`eval/success`, `attack/NAME/…`), repeatable."""


@dataclasses.dataclass(frozen=True, kw_only=True)
class Command:
    """Options every command takes."""

    plugin: Annotated[_Repeated, tyro.conf.arg(metavar="MODULE")] = ()
    """Load a plugin first: a module name or a .py file (repeatable)."""
    config: Annotated[str | None, tyro.conf.arg(metavar="FILE")] = None
    """Options from a TOML/YAML file (keys: option names); the command line overrides it."""

    all_cpu_cores: ClassVar[bool] = False
    """Whether the command shards seeds over one XLA device per CPU core (set before JAX
    is imported: `jax_setup.use_all_cpu_cores`)."""
    compiles: ClassVar[bool] = False
    """Whether the command compiles programs: its process enables the persistent
    compilation cache once the plugins (its key) are loaded, before anything compiles
    (`jax_setup.enable_compilation_cache`)."""

    def run(self, plugins: tuple[str, ...]) -> int:
        """Does the command (plugins loaded, names checked); the exit status.

        `plugins`: the plugins loaded, as a spawned sweep worker loads them again.
        """
        raise NotImplementedError(f"{type(self).__name__} is not a command of its own")

    def check(self) -> None:
        """Raises InvalidParameter (one line naming the option) on a value out of range;
        fields still `tyro.MISSING` (required, not given yet) are skipped."""
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


@dataclasses.dataclass(frozen=True, kw_only=True)
class Logging:
    """The --log option of the commands that train."""

    log: Annotated[
        _Repeated,
        tyro.conf.arg(
            metavar="BACKEND",
            help="Stream every metrics row and the config to a tracker: "
            f"{', '.join(TRACKERS)} (repeatable or comma-separated; "
            "pip install 'pimbot[tracking]').",
        ),
    ] = ()


def _defense_names(defenses) -> list[str]:
    return [name for name, _ in defenses]


def _defense_params(defenses) -> dict[str, dict]:
    return {name: dict(params) for name, params in defenses if params}


@dataclasses.dataclass(frozen=True, kw_only=True)
class Train(Logging, Command):
    """Train one learner on one environment, S seeds (rerun the same command to resume)."""

    env_id: Annotated[_EnvId, tyro.conf.Positional]
    """Environment id (see `pimbot envs`)."""
    env_params: _PositionalPairs = ()
    """Environment parameters, e.g. n_agents=4 min_at_lever=2 (see `pimbot envs`)."""
    learner: Annotated[str, tyro.conf.arg(metavar="NAME"), Registered("learners")] = "lio"
    """Learner (see `pimbot learners` for the names and their hyperparameters)."""
    hp: Annotated[_Pairs, *_option("NAME=VALUE"), FromRun("hparams")] = ()
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
    attack: Annotated[str | None, tyro.conf.arg(metavar="NAME"), Registered("attacks")] = None
    """Manipulate one agent (see `pimbot attacks`); None: a clean run."""
    attack_param: Annotated[
        _Pairs, *_option("NAME=VALUE", aliases=("--ap",)), FromRun("attack_params")
    ] = ()
    """Attack parameter (repeatable), e.g. --ap adversary=1 --ap mode=stealthy."""
    defense: Annotated[
        _Repeated,
        tyro.conf.arg(metavar="NAME"),
        Registered("defenses"),
        FromRun("defenses", _defense_names),
    ] = ()
    """Training-time defense of the honest agents (repeatable; see `pimbot defenses`)."""
    defense_param: Annotated[
        _Pairs,
        *_option("[DEFENSE.]NAME=VALUE", aliases=("--dp",)),
        FromRun("defenses", _defense_params),
    ] = ()
    """Defense parameter (repeatable), e.g. --dp health_monitor.patience=20."""
    audit_log: Annotated[str | None, tyro.conf.arg(metavar="PATH")] = None
    """Append a keyed (HMAC-SHA256) audit log of the run to this file."""
    audit_key: Annotated[str | None, tyro.conf.arg(metavar="FILE")] = None
    """Audit log key file, not in the log's directory (made 0600 if missing); None: default."""
    out: Annotated[str | None, tyro.conf.arg(metavar="DIR")] = None
    """Run directory (created; rerun to resume). Required unless --from is given."""
    from_run: Annotated[str | None, *_option("RUN_DIR", name="from")] = None
    """Rerun a saved run: its config gives every default; without --out, continue it."""
    restart: bool = False
    """Start the run in --out over: remove what a previous run wrote there first."""
    accept_changed_code: bool = False
    """Resume (or rerun with --from) a run made by another pimbot version or plugin code;
    the change is recorded in its config.json. Without it such a run is refused."""
    chunk_iterations: int = 2000
    """Iterations between checkpoints (≥ 1; whole eval periods; results unchanged)."""
    quiet: bool = False
    """No progress display."""

    all_cpu_cores: ClassVar[bool] = True
    compiles: ClassVar[bool] = True

    def int_bounds(self) -> dict[str, int]:
        return {
            "seeds": 1,
            "first_seed": 0,
            "iterations": 1,
            "eval_period": 1,
            "eval_episodes": 1,
            "chunk_iterations": 1,
        }

    def run(self, plugins: tuple[str, ...]) -> int:
        from pimbot.cli import handlers

        return handlers.cmd_train(self)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Table(Command):
    """Markdown table of finished runs' final metrics."""

    run_dirs: _Runs
    """Run directories."""
    metric: _Metrics = ()
    """Add a column of this metric's final value (any metrics.csv column; repeatable)."""

    def run(self, plugins: tuple[str, ...]) -> int:
        from pimbot.cli import handlers

        return handlers.cmd_table(self)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Plot(Command):
    """Learning curves of runs (mean ± 95 % CI) as PNG (an SVG is written beside it)."""

    run_dirs: _Runs
    """Run directories."""
    out: Annotated[str, tyro.conf.arg(metavar="FILE.png")]
    """PNG file to write."""
    metric: _Metrics = ()
    """Plot this metric (any metrics.csv column; repeatable, one panel each); none:
    eval/success and eval/return_ratio."""

    def run(self, plugins: tuple[str, ...]) -> int:
        from pimbot.cli import handlers

        return handlers.cmd_plot(self)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Profile(Command):
    """Decision latency, update cost and hardware traces of a controller (benign vs ADMO)."""

    env: _EnvId
    """Environment id (see `pimbot envs`)."""
    env_params: _PositionalPairs = ()
    """Environment parameters, e.g. n_agents=4 min_at_lever=2."""
    controller: Literal[CONTROLLERS] = "benign"
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

    compiles: ClassVar[bool] = True

    def int_bounds(self) -> dict[str, int]:
        return {"action_repeat": 1, "seed": 0}

    def positive_numbers(self) -> tuple[str, ...]:
        return ("duration", "sample_hz")

    def check(self) -> None:
        super().check()
        for name in ("hidden", "update_every"):
            values = getattr(self, name)
            if values is not tyro.MISSING:
                if not values:
                    raise InvalidParameter(f"{name}: give at least one value")
                for i, value in enumerate(values):
                    check_int(f"{name}[{i}]", value, 1, MAX_PROFILED_WIDTH)

    def run(self, plugins: tuple[str, ...]) -> int:
        from pimbot.cli import handlers

        return handlers.cmd_profile(self)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Suite(Logging, Command):
    """The options of the commands that run a suite of jobs (reproduce, sweep)."""

    only: Annotated[_Repeated, tyro.conf.arg(metavar="PATTERN")] = ()
    """Run only jobs whose <group>/<setting> name matches (repeatable; wildcards)."""
    backend: Literal[BACKENDS] = "local"
    """local: a process pool on this machine; ray: one Ray task per job."""
    workers: int = 0
    """Jobs at a time (≥ 0); 0: one per CPU core locally, all at once on Ray."""
    devices_per_job: int = 0
    """CPU cores each job shards its seeds over (≥ 0); 0: cores / workers."""
    ray_address: Annotated[str | None, tyro.conf.arg(metavar="ADDRESS")] = None
    """Ray cluster to join: auto or HOST:PORT; None: start a local one (--backend ray)."""
    list: bool = False
    """Print the plan (every job and its status) and exit."""
    accept_changed_code: bool = False
    """Resume jobs made by another pimbot version or plugin code (recorded in each job's
    config.json). Without it such a job is refused before anything runs."""
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
    """5 seeds and a fifth of the iterations: every setting and figure, in minutes."""

    def run(self, plugins: tuple[str, ...]) -> int:
        from pimbot.cli import handlers

        return handlers.cmd_reproduce(self, plugins)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Sweep(Suite):
    """Run a grid of envs × learners × attacks × defenses from a TOML file (resumable)."""

    grid: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="GRID.toml")]
    """Grid file (TOML; see docs/examples/grid.toml)."""

    def run(self, plugins: tuple[str, ...]) -> int:
        from pimbot.cli import handlers

        return handlers.cmd_sweep(self, plugins)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Report(Command):
    """report.md and report.html (figures, tables, claims) from a suite directory."""

    suite_dir: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="SUITE_DIR")]
    """Directory written by `pimbot reproduce` or `pimbot sweep`."""
    out: Annotated[str | None, tyro.conf.arg(metavar="DIR")] = None
    """Where to write; None: SUITE_DIR."""

    def run(self, plugins: tuple[str, ...]) -> int:
        from pimbot.cli import handlers

        return handlers.cmd_report(self)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Check(Command):
    """A canary run of a plugin file: is each hook called, and does it change anything?"""

    file: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="FILE.py")]
    """The plugin file (or module) to check; loaded as --plugin loads it."""
    env: Annotated[str | None, tyro.conf.arg(metavar="ENV_ID"), Registered("envs")] = None
    """Env of the runs; None: the file's own env if it registers one, else escape_room-v0."""
    learner: Annotated[str | None, tyro.conf.arg(metavar="NAME"), Registered("learners")] = None
    """Learner of the runs; None: the file's, else the default, else the first that fits."""
    defense_attack: Annotated[str | None, tyro.conf.arg(metavar="NAME"), Registered("attacks")] = (
        "fake_incentive"
    )
    """Check each defense under this attack as well as clean (None: clean only)."""
    seeds: int = 2
    """Seeds of each canary run (1 to 16)."""
    iterations: int = 20
    """Training iterations of each canary run (1 to 10000)."""

    compiles: ClassVar[bool] = True

    def int_bounds(self) -> dict[str, int]:
        return {"seeds": 1, "iterations": 1}

    def run(self, plugins: tuple[str, ...]) -> int:
        from pimbot.cli.check import cmd_check

        return cmd_check(self)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Envs(Command):
    """List the environments, their parameters (defaults, meaning) and learner defaults."""

    def run(self, plugins: tuple[str, ...]) -> int:
        from pimbot.cli.listing import print_envs

        return print_envs()


@dataclasses.dataclass(frozen=True, kw_only=True)
class Learners(Command):
    """List the learners, their hyperparameters (defaults, meaning) and hook points."""

    def run(self, plugins: tuple[str, ...]) -> int:
        from pimbot.cli.listing import print_learners

        return print_learners()


@dataclasses.dataclass(frozen=True, kw_only=True)
class Attacks(Command):
    """List the attacks, their parameters (defaults, meaning) and hook points."""

    def run(self, plugins: tuple[str, ...]) -> int:
        from pimbot.cli.listing import print_attacks

        return print_attacks()


@dataclasses.dataclass(frozen=True, kw_only=True)
class Defenses(Command):
    """List the defenses and their parameters (defaults, meaning)."""

    def run(self, plugins: tuple[str, ...]) -> int:
        from pimbot.cli.defenses import cmd_defenses

        return cmd_defenses()


@dataclasses.dataclass(frozen=True, kw_only=True)
class AuditVerify(Command):
    """Verify a keyed audit log and its signed head; names the first bad record."""

    log: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="LOG")]
    """The JSONL audit log."""
    head: str | None = None
    """A head MAC printed when the log was written; the log must contain it."""
    audit_key: Annotated[str | None, tyro.conf.arg(metavar="FILE")] = None
    """The log's key file; None: $PIMBOT_AUDIT_KEY_FILE, else ~/.config/pimbot/audit.key."""

    def run(self, plugins: tuple[str, ...]) -> int:
        from pimbot.cli.defenses import cmd_audit

        return cmd_audit(self)


@dataclasses.dataclass(frozen=True, kw_only=True)
class RobotRun(Command):
    """The options of the commands that play a trained Escape Room run with robots."""

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
    bag_storage: Literal[BAG_STORAGES] = "mcap"
    """The bag's storage: mcap (rosbag2's default since Iron) or sqlite3 (Humble's)."""
    ros_distro: Literal[ROS_DISTROS] = "jazzy"
    """The bag's message types: jazzy (cmd_vel as TwistStamped) or humble (plain Twist)."""
    json: Annotated[str | None, tyro.conf.arg(metavar="FILE")] = None
    """Write the results as JSON to this file."""
    physics: Annotated[tuple[str, ...], tyro.conf.arg(metavar="NAME=VALUE"), PAIRS] = ()
    """Physics settings, e.g. actuation_noise=0.2 decision_time_limit=15."""

    def int_bounds(self) -> dict[str, int]:
        return {"episodes": 1}

    def run(self, plugins: tuple[str, ...]) -> int:
        from pimbot.cli.robot import cmd_eval

        return cmd_eval(self)


@dataclasses.dataclass(frozen=True, kw_only=True)
class RobotRender(RobotRun):
    """Top-down video of one physics episode (.gif, or .mp4 with ffmpeg)."""

    out: Annotated[str, tyro.conf.arg(metavar="VIDEO")]
    """Video file: .gif, or .mp4 (needs ffmpeg)."""
    seed_index: int = 0
    """Which seed of the run (≥ 0)."""
    episode: int = 0
    """Which episode of that seed (≥ 0)."""
    renderer: Literal[RENDERERS] = "auto"
    """auto: MuJoCo if OpenGL works here, else matplotlib."""
    frame: Annotated[str | None, tyro.conf.arg(metavar="FRAME.png")] = None
    """Also write the episode's last frame as this PNG."""

    def int_bounds(self) -> dict[str, int]:
        return {"seed_index": 0, "episode": 0}

    def run(self, plugins: tuple[str, ...]) -> int:
        from pimbot.cli.robot import cmd_render

        return cmd_render(self)


@dataclasses.dataclass(frozen=True, kw_only=True)
class RobotWire(Command):
    """Options of the commands on the ROS 2 wire (DDS through cyclonedds, no ROS needed)."""

    ros_distro: Literal[ROS_DISTROS] = "jazzy"
    """The cmd_vel type: jazzy (TwistStamped, TurtleBot3 on Jazzy) or humble (Twist)."""
    domain_id: int = 0
    """The DDS domain (ROS_DOMAIN_ID); Cyclone DDS itself is configured by CYCLONEDDS_URI."""
    json: Annotated[str | None, tyro.conf.arg(metavar="FILE")] = None
    """Write the results as JSON to this file."""
    physics: Annotated[tuple[str, ...], tyro.conf.arg(metavar="NAME=VALUE"), PAIRS] = ()
    """Episode settings, e.g. decision_time_limit=15 settle_time=1."""

    def int_bounds(self) -> dict[str, int]:
        return {"domain_id": 0}


@dataclasses.dataclass(frozen=True, kw_only=True)
class RobotServe(RobotWire):
    """Drive robots on ROS 2 topics with a trained run: odom in, cmd_vel out, per robot."""

    run_dir: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="RUN_DIR")]
    """A pimbot run directory of escape_room-v0."""
    seed_index: int = 0
    """Which seed of the run (≥ 0)."""
    layout: Annotated[str | None, tyro.conf.arg(metavar="FILE.json")] = None
    """The room as JSON (what /pimbot/layout carries); None: wait for it on that topic."""
    attack: Annotated[str | None, tyro.conf.arg(metavar="NAME"), Registered("attacks")] = None
    """Apply this attack live (default parameters) instead of the run's own."""
    adversary: int = 0
    """The manipulated robot of --attack (≥ 0)."""
    authenticated: bool = False
    """Sign incentive messages (HMAC-SHA256, per-pair keys) and verify them on receipt."""
    audit_log: Annotated[str | None, tyro.conf.arg(metavar="PATH")] = None
    """Append a keyed (HMAC-SHA256) audit record of every decision to this file."""
    audit_key: Annotated[str | None, tyro.conf.arg(metavar="FILE")] = None
    """The audit key file; None: $PIMBOT_AUDIT_KEY_FILE, else ~/.config/pimbot/audit.key."""
    timeout: float = 60.0
    """Wall seconds to wait for the room and for odometry before giving up."""
    odometry_timeout: float = 0.5
    """Wall seconds a robot's odometry may be silent before every robot gets a zero cmd_vel
    (driving resumes when it is back)."""

    def int_bounds(self) -> dict[str, int]:
        return {"domain_id": 0, "seed_index": 0, "adversary": 0}

    def positive_numbers(self) -> tuple[str, ...]:
        return ("timeout", "odometry_timeout")

    def run(self, plugins: tuple[str, ...]) -> int:
        from pimbot.cli.robot import cmd_serve

        return cmd_serve(self)


@dataclasses.dataclass(frozen=True, kw_only=True)
class RobotWorld(RobotWire):
    """The MuJoCo robots on ROS 2 topics (cmd_vel in, odom out) for `pimbot robot serve`."""

    robots: int = 2
    """N, the robots (≥ 2)."""
    min_at_lever: int = 1
    """M, robots in the lever zone that hold the gate open (1 ≤ M < N)."""
    seed: int = 0
    """The room's randomness (layout, start poses, noise)."""
    nominal_room: bool = False
    """The fixed room instead of a random layout."""
    speed: float = 1.0
    """Real-time factor (> 0; 1 = real time)."""
    lockstep: bool = False
    """Step as soon as every robot's command answers the last odometry (ignores --speed)."""
    command_timeout: float = 1.0
    """Wall seconds a control period waits for the commands before stepping without them."""
    timeout: float = 600.0
    """Wall seconds after which the world stops if the controller has not ended."""

    def int_bounds(self) -> dict[str, int]:
        return {"domain_id": 0, "robots": 2, "min_at_lever": 1, "seed": 0}

    def positive_numbers(self) -> tuple[str, ...]:
        return ("speed", "command_timeout", "timeout")

    def run(self, plugins: tuple[str, ...]) -> int:
        from pimbot.cli.robot import cmd_world

        return cmd_world(self)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Export(Command):
    """Each agent's trained policy (and incentive function) of one seed as ONNX + policy.json."""

    run_dir: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="RUN_DIR")]
    """A finished or checkpointed pimbot run directory."""
    out: Annotated[str, tyro.conf.arg(metavar="DIR")]
    """Directory to write: new, empty, or a previous export (replaced)."""
    seed: Annotated[int | None, tyro.conf.arg(metavar="SEED")] = None
    """Which seed of the run (≥ 0); None: its first seed."""
    accept_changed_code: bool = False
    """Export a run made by another pimbot version or plugin code (recorded in policy.json).
    Without it such a run is refused."""

    def int_bounds(self) -> dict[str, int]:
        return {"seed": 0}

    def run(self, plugins: tuple[str, ...]) -> int:
        from pimbot.robot.export import export_run

        sidecar = export_run(self.run_dir, self.out, self.seed, self.accept_changed_code)
        files = [a[k]["file"] for a in sidecar["agents"] for k in ("policy", "incentive") if a[k]]
        print(f"wrote {self.out}: {', '.join(files)}, policy.json")
        print(f"seed {sidecar['seed']}, iteration {sidecar['iteration']}")
        parity = sidecar["parity"]
        largest = ", ".join(f"{k} {v:.2g}" for k, v in parity["max_abs_difference"].items())
        print(
            f"onnxruntime vs pimbot on {parity['observations_per_agent']} observations per "
            f"agent, largest difference: {largest}"
        )
        return 0


COMMANDS: dict[tuple[str, ...], type[Command]] = {
    ("train",): Train,
    ("sweep",): Sweep,
    ("reproduce",): Reproduce,
    ("report",): Report,
    ("table",): Table,
    ("plot",): Plot,
    ("profile",): Profile,
    ("check",): Check,
    ("envs",): Envs,
    ("learners",): Learners,
    ("attacks",): Attacks,
    ("defenses",): Defenses,
    ("audit", "verify"): AuditVerify,
    ("robot", "eval"): RobotEval,
    ("robot", "render"): RobotRender,
    ("robot", "serve"): RobotServe,
    ("robot", "world"): RobotWorld,
    ("export",): Export,
}
"""Every command path and the class that parses and runs it: the one dispatch table."""

GROUPS: dict[tuple[str, ...], str] = {
    ("audit",): "Tamper-evident audit logs.",
    ("robot",): "Trained Escape Room policies on TurtleBot3-sized robots in MuJoCo.",
}
"""The commands that only group subcommands, and what each is for."""


def build(choices: object = None) -> dict:
    """The command tree: name -> command class, or name -> {"": what the group is for,
    subcommand: class, ...}, in the order of `COMMANDS`.

    `choices` is ignored: the registries' names are no longer built into the classes (they
    are checked after parsing); it is accepted for callers written before.
    """
    tree: dict = {}
    for path, cls in COMMANDS.items():
        node = tree
        for depth, name in enumerate(path[:-1]):
            node = node.setdefault(name, {"": GROUPS[path[: depth + 1]]})
        node[path[-1]] = cls
    return tree


def summary(node) -> str:
    """The first line of a command's docstring; a group's own line and its subcommands."""
    if isinstance(node, dict):
        return f"{node['']} ({', '.join(n for n in node if n)})"
    return ((node.__doc__ or "").strip().splitlines() or [""])[0]
