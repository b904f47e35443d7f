"""The paper's experiment suite as data: every job `pimbot reproduce` plans.

A job is one run directory: a training run (a `RunConfig`) or a paired
on-device profile. Jobs are named `<group>/<setting>`; the group is the
directory the job writes under and the report section that reads it.

`suite(quick=False)` is the published budget (10 seeds, the paper's
iterations); `suite(quick=True)` keeps every setting, figure and claim but
runs `QUICK_SEEDS` (5) seeds on a fifth of the iterations, so the whole pipeline
finishes in minutes on a laptop. Claims judged on the quick budget are marked as
such by the report, and those whose rule is stated at a horizon the quick budget
does not reach are named undecidable there by design.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from pimbot import envs
from pimbot.profiling.decision_loop import ProfileConfig
from pimbot.suites import grid
from pimbot.suites.jobs import Job

SHARED_UPDATES = (("incentive_updates", "shared"),)
"""N ≥ 3 LIO runs use the original code's shared incentive updates (the default, named
explicitly where it matters; docs/deviations.md)."""


@dataclasses.dataclass(frozen=True)
class Scale:
    """How much of the published budget a suite runs."""

    name: str
    seeds: int
    iteration_fraction: float
    min_evals: int
    """Every run keeps at least this many evaluation points (curves and convergence)."""
    profile_seconds: float
    robot_episodes: int
    """Physics episodes per seed when a trained Escape Room run is evaluated on robots."""
    full_matrices: bool = True
    """False: the defense matrix and the robot evaluation keep a representative slice."""


QUICK_SEEDS = 5
"""Seeds of every quick job: the fewest at which the report's tests can decide. A one-sided
sign-flip test's smallest p-value is 2^−n (5 seeds: 0.031 < 0.05; 3 seeds: 0.125), a
permutation test of two runs' means 1 / C(2n, n) (5 + 5 seeds: 0.004; 3 + 3: 0.05), and
from 5 seeds an interval is a BCa bootstrap CI rather than the range
(`statistics.MIN_SEEDS_FOR_CI`)."""
FULL = Scale("full", 10, 1.0, min_evals=10, profile_seconds=20.0, robot_episodes=10)
QUICK = Scale(
    "quick",
    QUICK_SEEDS,
    0.2,
    min_evals=10,
    profile_seconds=3.0,
    robot_episodes=1,
    full_matrices=False,
)
QUICK_DEFENSE_SLICE = ("er21", ("clean", "fake_incentive", "bypass"), ("guard", "all"))
"""(setting, attacks, defense sets) the quick suite keeps of the defense matrix."""
QUICK_ROBOT_CONDITIONS = ("clean", "bypass")
"""The quick suite drives these runs of each ER config (the redundancy effect)."""


@dataclasses.dataclass(frozen=True)
class Setting:
    """An environment at the paper's budget."""

    label: str
    env_id: str
    env_params: tuple[tuple[str, Any], ...]
    iterations: int
    eval_period: int | None = None
    hparams: tuple[tuple[str, Any], ...] = ()


ATTACK_SETTINGS = (
    Setting("er21", "escape_room-v0", (), 50_000),
    Setting(
        "er42",
        "escape_room-v0",
        (("min_at_lever", 2), ("n_agents", 4)),
        25_000,
        hparams=SHARED_UPDATES,
    ),
    Setting(
        "er43",
        "escape_room-v0",
        (("min_at_lever", 3), ("n_agents", 4)),
        25_000,
        hparams=SHARED_UPDATES,
    ),
    Setting("ipd", "ipd-v0", (), 20_000, eval_period=500),
)

ATTACK_CONDITIONS: dict[str, tuple[str | None, tuple[tuple[str, Any], ...]]] = {
    "clean": (None, ()),
    "self_centered": ("self_centered", ()),
    "fake_incentive": ("fake_incentive", (("amount", 10.0),)),
    "fake_incentive_c50": ("fake_incentive", (("amount", 50.0),)),
    "bypass": ("bypass", ()),
    "reverse": ("reverse", ()),
    "admo_stealthy": ("admo", (("mode", "stealthy"),)),
    "admo_disrupt": ("admo", (("mode", "disrupt"),)),
    "admo_code_stealthy": ("admo_code", (("mode", "stealthy"),)),
    "admo_code_disrupt": ("admo_code", (("mode", "disrupt"),)),
}
"""Run conditions by label; `admo_code_*` is the published code's ADMO (extra ordinary
steps), `admo_*` the paper's (attacks/admo_code.py). `fake_incentive` gives the original
code's 10 per step per recipient (greedy_agent, lio/alg/lio_agent_greedy.py `give_reward`; its
logs were made at it), `fake_incentive_c50` the paper's text's C = 50 (Escape Room only)."""
ER_ONLY_CONDITIONS = ("fake_incentive_c50",)
"""Conditions of C2, a claim about Escape Room: not run on the IPD."""

ADMO_CODE_CONDITIONS = ("admo_code_disrupt", "admo_code_stealthy")
QUICK_ADMO_CODE_CONDITIONS = ("admo_code_disrupt",)
"""The quick suite runs the code's default mode ("adversarial" = disrupt) only."""
ADMO_CODE_LEARNER_RATES = {"ipd": (("lr_cost", 0.0),)}
"""admo_code's own incentive steps use the learner's rates: LIO's IPD column has no cost
step (lr_cost 0); the Escape Room column is admo_code's default."""

STAG_HUNT_SETTINGS = tuple(
    Setting(
        f"sh{n}",
        "stag_hunt-v0",
        (("n_players", n),),
        5_000,
        eval_period=100,
        hparams=SHARED_UPDATES if n >= 3 else (),
    )
    for n in (2, 3, 4)
)


def scaled(setting: Setting, scale: Scale) -> tuple[int, int | None]:
    """(iterations, eval_period) of `setting` under `scale`, keeping ≥ min_evals points."""
    if scale.iteration_fraction == 1.0:
        return setting.iterations, setting.eval_period
    period = setting.eval_period or envs.spec(setting.env_id).eval_period
    iterations = int(setting.iterations * scale.iteration_fraction)
    evals = max(scale.min_evals, iterations // period)
    eval_period = max(1, iterations // evals)
    return eval_period * evals, eval_period


def grid_env(setting: Setting, scale: Scale) -> grid.EnvEntry:
    """`setting` as a grid env entry under `scale` (its own budget and hparams)."""
    iterations, eval_period = scaled(setting, scale)
    return grid.EnvEntry(
        setting.env_id,
        setting.env_params,
        label=setting.label,
        iterations=iterations,
        eval_period=eval_period,
        hparams=setting.hparams,
    )


NO_DEFENSE = grid.DefenseEntry()


def paper_grid(
    group: str,
    settings: tuple[Setting, ...],
    conditions: tuple[str, ...],
    scale: Scale,
    learner: str = "lio",
    defense: grid.DefenseEntry = NO_DEFENSE,
) -> grid.Grid:
    """Settings × conditions (`ATTACK_CONDITIONS` keys) of one learner, named
    `<group>/<setting>_<condition>[_<defense>]` (the learner is left out of the names)."""
    return grid.Grid(
        name=group,
        envs=tuple(grid_env(s, scale) for s in settings),
        learners=(grid.LearnerEntry(learner, label=""),),
        seeds=scale.seeds,
        attacks=tuple(grid.AttackEntry(*ATTACK_CONDITIONS[c], label=c) for c in conditions),
        defenses=(defense,),
    )


PAPER_CONDITIONS = tuple(c for c in ATTACK_CONDITIONS if c not in ADMO_CODE_CONDITIONS)


def admo_code_grid(setting: Setting, conditions: tuple[str, ...], scale: Scale) -> grid.Grid:
    """`attacks/<setting>_admo_code_<mode>`: the code's ADMO with the learner's rates."""
    rates = ADMO_CODE_LEARNER_RATES.get(setting.label, ())
    return dataclasses.replace(
        paper_grid("attacks", (setting,), (), scale),
        attacks=tuple(
            grid.AttackEntry(
                ATTACK_CONDITIONS[c][0], tuple(sorted(ATTACK_CONDITIONS[c][1] + rates)), label=c
            )
            for c in conditions
        ),
    )


NOISE_LIMITED = ("er42_clean", "er42_self_centered", "er43_clean", "er43_reverse")
NOISE_LIMITED += ("er43_admo_stealthy",)
"""Attack jobs whose claim parts the paper's 10 seeds cannot decide (C1b ER(4,2)'s first
crossing, C4 ER(4,3), C5 ER(4,3)'s stealthy margin): `NOISE_LIMITED_SEEDS` at full scale."""
NOISE_LIMITED_SEEDS = 40
"""Seeds 0..39: the first 10 are the paper's 10 (a run's seeds do not depend on the batch)."""


def attack_jobs(scale: Scale) -> list[Job]:
    """C1–C5: clean LIO and every attack on ER(2,1), ER(4,2), ER(4,3) and the 2-player IPD;
    for C5 also the published code's ADMO (`admo_code`) beside the paper's; at full scale
    the noise-limited jobs run `NOISE_LIMITED_SEEDS` seeds."""
    claims = {
        "clean": ("C1", "C2", "C3", "C4", "C5"),
        "self_centered": ("C1",),
        "fake_incentive": ("C2",),
        "fake_incentive_c50": ("C2",),
        "bypass": ("C3",),
        "reverse": ("C4",),
        "admo_stealthy": ("C5",),
        "admo_disrupt": ("C5",),
        "admo_code_stealthy": ("C5",),
        "admo_code_disrupt": ("C5",),
    }
    code = ADMO_CODE_CONDITIONS if scale.full_matrices else QUICK_ADMO_CODE_CONDITIONS
    cells = grid.expand_cells(paper_grid("attacks", ATTACK_SETTINGS, PAPER_CONDITIONS, scale))
    cells = [
        c
        for c in cells
        if c.attack.label not in ER_ONLY_CONDITIONS or c.job.spec.env_id == "escape_room-v0"
    ]
    for setting in ATTACK_SETTINGS:
        cells += grid.expand_cells(admo_code_grid(setting, code, scale))
    return [
        dataclasses.replace(c.job, claims=claims[c.attack.label], spec=_seeds(c.job, scale))
        for c in cells
    ]


def _seeds(job: Job, scale: Scale):
    """`job`'s run config, with `NOISE_LIMITED_SEEDS` seeds where the full suite needs them."""
    name = job.name.split("/", 1)[1]
    if scale.name != FULL.name or name not in NOISE_LIMITED:
        return job.spec
    return dataclasses.replace(job.spec, seeds=NOISE_LIMITED_SEEDS)


STAG_HUNT_CODE_ADMO = grid.AttackEntry("negated_env_reward", (), label="negated_env_reward")
"""The published code's Stag Hunt ADMO: the adversary learns on its env reward negated
(attacks/negated_env_reward.py); a Stag Hunt condition only, not one of the attack grid's."""


def stag_hunt_jobs(scale: Scale) -> list[Job]:
    """C6: LIO baseline vs the paper's ADMO (disrupt) and the code's Stag Hunt ADMO on the
    Stag Hunt gridworld, N = 2, 3, 4."""
    paper = paper_grid("stag_hunt", STAG_HUNT_SETTINGS, ("clean", "admo_disrupt"), scale)
    both = dataclasses.replace(paper, attacks=(*paper.attacks, STAG_HUNT_CODE_ADMO))
    return [dataclasses.replace(job, claims=("C6",)) for job in grid.expand(both)]


def profile_jobs(scale: Scale) -> list[Job]:
    """C8: the decision loop on this machine, benign then ADMO, everything else identical."""
    config = ProfileConfig(duration_s=scale.profile_seconds)
    return [Job("profile/er21_paired", "profile", config, ("C8",))]


GRUDGE = (("grudge", "one_step"),)
"""Stag Hunt gridworld Reciprocator runs use the original IPD agent's one-step grudge with the
learned VoI (docs/reciprocators.md); on the IPD that agent is the default, on Escape
Room the credit − debit balance at the PIMbot script's learner settings is."""
SPEC_BALANCE = (
    ("voi", "learned"),
    ("grudge", "accumulated"),
    ("policy_hidden", (64, 64)),
    ("voi_refit_period", 2),
    ("voi_history", 3),
)
"""The spec's general agent on the IPD: learned VoI, accumulated balance, 64×64 networks."""


CODE_ER_BALANCE = (("grudge", "petty"),)
"""The PIMbot code's Escape Room script's balance: 'linear' → the credit-only `petty_rr` of
johnlyzhou/reciprocator (greedy_agent `reciprocators/run_er.py`), in place of the default
credit − debit, all else at the defaults (docs/reciprocators.md#escape-room)."""
CODE_ER_RECIPROCATOR = (
    ("num_envs", 1),
    ("voi_minibatch_rows", "distinct_weighted"),
    *CODE_ER_BALANCE,
)
"""The published code's Reciprocator Escape Room script as it runs (reciprocators/run_er*.py):
its learner settings are the registry's Escape Room defaults (PPO lr 1e-4, γ 0.99, entropy
0.01, w 5, VoI lr 1e-3), which play 128 episodes per update, with its credit-only petty
balance; the script plays one episode per update, 5000 episodes (and logs no success). Each refit
step evaluates its few stored samples once, weighted by their draws: the same loss as every
draw, about 10× faster at one episode per update (docs/reciprocators.md)."""
CODE_ER_EPISODES = 5000
RECIPROCATOR_ER_UPDATES = 300
"""Updates of the C7 Escape Room runs at the defaults' 128 episodes per update."""
IPD_GAMES = 2048
"""Games per update of the C7 IPD runs, quick and full: the original trainer's
(configs/ipd.yaml) and the matrix default."""
SPEC_IPD_GAMES = 32
"""Games per update of the spec's learned-VoI agent on the IPD (one update of 2048 games took
43 s for one seed on 2 busy cores)."""
TRANSFER_ENV = "escape_room_transfer-v0"
TRANSFER = (("transfer", 0.5),)
"""The counterfactual pay-back channel: a door-goer may give half its step reward away."""


def _reciprocator_settings(scale: Scale) -> list[tuple[Setting, str, tuple[str, ...]]]:
    """(setting, learner, conditions) of C7 and the 2-player IPD fidelity runs."""

    def ipd(label, n, hparams=(), games_per_update=None):
        params = (("max_steps", 32), ("n_players", n))
        hparams = (("num_envs", games_per_update or IPD_GAMES),) + hparams
        return Setting(label, "ipd-v0", params, 100, 5, hparams)

    def room(label, n, m, env_id="escape_room-v0", extra=(), hparams=()):
        params = (("min_at_lever", m), ("n_agents", n)) + extra
        return Setting(label, env_id, params, RECIPROCATOR_ER_UPDATES, 10, hparams)

    def code_room(label, n, m):  # the code's batch of one episode per update
        params = (("min_at_lever", m), ("n_agents", n))
        return Setting(label, "escape_room-v0", params, CODE_ER_EPISODES, 100, CODE_ER_RECIPROCATOR)

    def hunt(label, n):
        return Setting(
            label, "stag_hunt-v0", (("n_players", n),), 60, 5, (("num_envs", 16),) + GRUDGE
        )

    disrupt = ("clean", "admo_disrupt")
    settings = [
        (ipd("rec_ipd2", 2), "reciprocator", ("clean", "self_centered", "admo_disrupt")),
        (ipd("nl_ipd2", 2), "nl", ("clean",)),
        # the spec's learned VoI costs ~40 s per update at 2048 games: it plays 32
        (ipd("rec_ipd2_spec", 2, SPEC_BALANCE, SPEC_IPD_GAMES), "reciprocator", ("clean",)),
        (ipd("rec_ipd3", 3), "reciprocator", disrupt),
        (ipd("rec_ipd4", 4), "reciprocator", disrupt),
        (room("rec_er21", 2, 1), "reciprocator", disrupt),
        (room("nl_er21", 2, 1), "nl", ("clean",)),
        # the same settings with the PIMbot code's ER script's credit-only balance ('linear'
        # → petty_rr), which learns to stay at the start (docs/reciprocators.md#escape-room)
        (room("rec_er21_petty", 2, 1, hparams=CODE_ER_BALANCE), "reciprocator", disrupt),
        (room("rec_er42", 4, 2), "reciprocator", disrupt),
        (room("rec_er42_petty", 4, 2, hparams=CODE_ER_BALANCE), "reciprocator", disrupt),
        (room("rec_er43", 4, 3), "reciprocator", disrupt),
        (room("rec_er43_petty", 4, 3, hparams=CODE_ER_BALANCE), "reciprocator", disrupt),
        (hunt("rec_sh2", 2), "reciprocator", disrupt),
        (hunt("rec_sh3", 3), "reciprocator", disrupt),
        (hunt("rec_sh4", 4), "reciprocator", disrupt),
        # C7-ER at the published code's batch of one episode per update (slow per episode:
        # the quick suite runs its ER(2,1) baseline only)
        (
            code_room("rec_er21_code_e1", 2, 1),
            "reciprocator",
            disrupt if scale.full_matrices else ("clean",),
        ),
        # COUNTERFACTUAL env (escape_room_transfer-v0): does a pay-back channel make
        # Reciprocators solve ER(2,1)? NL on it is the control (transfer without reciprocity)
        (room("rec_er21_transfer", 2, 1, TRANSFER_ENV, TRANSFER), "reciprocator", ("clean",)),
        (room("nl_er21_transfer", 2, 1, TRANSFER_ENV, TRANSFER), "nl", ("clean",)),
    ]
    if scale.full_matrices:
        settings += [
            (code_room("rec_er42_code_e1", 4, 2), "reciprocator", ("clean",)),
            (code_room("rec_er43_code_e1", 4, 3), "reciprocator", ("clean",)),
        ]
    return settings


def reciprocator_jobs(scale: Scale) -> list[Job]:
    """C7: Reciprocators clean vs ADMO (ER, IPD N = 2, 3, 4, Stag Hunt N = 2, 3, 4; ER also
    with the PIMbot code's credit-only petty balance), NL on ER(2,1), ER(2,1) at the
    published code's batch of one episode per update, the counterfactual transfer Escape
    Room, and the 2-player IPD fidelity runs (NL vs NL, NL vs Reciprocator, the spec's
    balance); the full suite adds ER(4,2) and ER(4,3) at the code's batch of one."""
    return [
        dataclasses.replace(job, claims=("C7",))
        for setting, learner, conditions in _reciprocator_settings(scale)
        for job in grid.expand(
            paper_grid("reciprocators", (setting,), conditions, scale, learner=learner)
        )
    ]


DEFENSE_SETTINGS = (
    Setting("er21", "escape_room-v0", (), 20_000),
    Setting(
        "er43",
        "escape_room-v0",
        (("min_at_lever", 3), ("n_agents", 4)),
        10_000,
        hparams=SHARED_UPDATES,
    ),
    Setting("ipd", "ipd-v0", (), 10_000, eval_period=500),
)
"""Reduced from the attack budgets (ER(2,1) 20k of 50k, ER(4,3) 10k of 25k, IPD 10k of
20k) so the defended matrix fits 2 cores; the no-defense column is the attack group's
runs read up to the same iteration (docs/defenses.md#measured)."""

DEFENSE_SETS = {
    "guard": ("incentive_guard",),
    "floor": ("exploration_floor",),
    "monitor": ("health_monitor",),
    "all": ("incentive_guard", "exploration_floor", "health_monitor"),
    "guard_monitor": ("incentive_guard", "health_monitor"),
}
DEFENDED_ATTACKS = ("clean", "fake_incentive", "bypass", "reverse", "self_centered", "admo_disrupt")


def defense_jobs(scale: Scale) -> list[Job]:
    """The defense matrix: {clean, each attack} × {each defense, all} on ER(2,1), ER(4,3),
    IPD, plus guard + monitor without the floor on clean and fake-incentive ER."""
    env_kept, attacks_kept, defenses_kept = QUICK_DEFENSE_SLICE
    jobs = []
    for label, names in DEFENSE_SETS.items():
        defense = grid.DefenseEntry(tuple((n, ()) for n in names), label=label)
        for setting in DEFENSE_SETTINGS:
            conditions = tuple(
                condition
                for condition in DEFENDED_ATTACKS
                if (
                    scale.full_matrices
                    or (
                        setting.label == env_kept
                        and condition in attacks_kept
                        and label in defenses_kept
                    )
                )
                and (
                    label != "guard_monitor"
                    or (
                        setting.env_id == "escape_room-v0"
                        and condition in ("clean", "fake_incentive")
                    )
                )
            )
            if not conditions:
                continue
            cells = grid.expand_cells(
                paper_grid("defenses", (setting,), conditions, scale, defense=defense)
            )
            jobs += [
                dataclasses.replace(c.job, after=(f"attacks/{setting.label}_{c.attack.label}",))
                for c in cells
            ]
    return jobs


@dataclasses.dataclass(frozen=True)
class RobotEval:
    """A trained run (a suite job name) evaluated in MuJoCo physics."""

    run: str
    episodes: int
    physics: tuple[tuple[str, Any], ...] = ()
    """`PhysicsConfig` overrides (noise, time limits, layout randomization)."""


def robot_jobs(scale: Scale) -> list[Job]:
    """Fig. 9: every trained Escape Room policy of the attack group, driven by robots."""
    return [
        Job(
            f"robot/{job.name.split('/', 1)[1]}",
            "robot_eval",
            RobotEval(job.name, scale.robot_episodes),
            after=(job.name,),
        )
        for job in attack_jobs(scale)
        if job.spec.env_id == "escape_room-v0"
        and job.spec.attack != "admo_code"  # compared in training only
        and (scale.full_matrices or job.name.split("_", 1)[1] in QUICK_ROBOT_CONDITIONS)
    ]


GROUPS = {
    "attacks": attack_jobs,
    "stag_hunt": stag_hunt_jobs,
    "reciprocators": reciprocator_jobs,
    "defenses": defense_jobs,
    "profile": profile_jobs,
    "robot": robot_jobs,
}
"""Suite groups in run order; each maps a Scale to its jobs."""


def _former_reciprocator_names() -> dict[str, str]:
    """The Escape Room Reciprocator jobs renamed on 2026-12-07 (0.2.0), when the default
    balance became credit − debit: `rec_erNM_*` was `rec_erNM_spec_*`, and the script's
    petty rows `rec_erNM_petty_*` were `rec_erNM_*`."""
    former = {}
    for room in ("er21", "er42", "er43"):
        for condition in ("clean", "admo_disrupt"):
            former[f"rec_{room}_{condition}"] = f"rec_{room}_spec_{condition}"
            former[f"rec_{room}_petty_{condition}"] = f"rec_{room}_{condition}"
    return {f"reciprocators/{new}": f"reciprocators/{old}" for new, old in former.items()}


FORMER_JOB_NAMES = _former_reciprocator_names()
"""A job's name in suites made before it was renamed (new name → former name), so that a
report still counts the finished jobs of an older suite directory; the runs themselves
are read by what their config.json records, never by their name."""


def suite(quick: bool = False) -> list[Job]:
    """Every job of the paper's suite, at the published budget or the quick one."""
    scale = QUICK if quick else FULL
    jobs = [job for make_jobs in GROUPS.values() for job in make_jobs(scale)]
    names = [job.name for job in jobs]
    assert len(names) == len(set(names)), "job names must be unique"
    return jobs
