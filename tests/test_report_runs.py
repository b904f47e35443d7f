"""`pimbot report` on runs it has never heard of: labels derived from configs, never a crash.

One real tiny training run is copied into a synthetic suite directory and its
config.json patched to an attack, an env id and a defense that no registry of
this process knows (as a plugin's runs would read on a machine without the
plugin), in a paper group and in a user's sweep group.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from pimbot.analysis import report, runs
from pimbot.suites import sweep
from pimbot.training import store

PLUGIN_ATTACK = "plugin_attack"
PLUGIN_ENV = "crystal_maze-v1"
PLUGIN_DEFENSE = "tripwire"


def _patch(run_dir: Path, attack=None, env_id=None, defense=None) -> None:
    path = run_dir / store.CONFIG
    config = json.loads(path.read_text())
    identity, run = config["identity"], config["run_config"]
    if attack:
        identity["attack"] = run["attack"] = attack
        identity["attack_params"] = {"adversary": 0, "strength": 3.0, "style": "sneaky"}
        run["attack_params"] = [["strength", 3.0], ["style", "sneaky"]]
    if env_id:
        identity["env_id"] = run["env_id"] = config["env"]["id"] = env_id
    if defense:
        run["defenses"] = [[defense, [["sensitivity", 2]]]]
    path.write_text(json.dumps(config))


@pytest.fixture(scope="module")
def suite(tmp_path_factory) -> Path:
    from pimbot.training.config import RunConfig
    from pimbot.training.runner import train

    root = tmp_path_factory.mktemp("suite")
    real = root / "_real"
    # The small run of test_runner and test_cli: one compiled program (persistent cache).
    run = RunConfig(
        env_id="escape_room-v0", seeds=2, iterations=200, eval_period=100, eval_episodes=4
    )
    train(run, real, progress=False)
    layout = {
        "attacks/er21_clean": {},
        "attacks/er21_plugin": {"attack": PLUGIN_ATTACK},
        "mygrid/er21_lio_clean": {},
        "mygrid/er21_lio_plugin": {"attack": PLUGIN_ATTACK},
        "mygrid/maze_lio_clean": {"env_id": PLUGIN_ENV},
        "mygrid/er21_lio_clean_tripwire": {"defense": PLUGIN_DEFENSE},
    }
    for name, patch in layout.items():
        shutil.copytree(real, root / name, ignore=shutil.ignore_patterns("checkpoint"))
        _patch(root / name, **patch)
    shutil.rmtree(real)
    jobs = [
        {"name": n, "group": n.split("/")[0], "kind": "train", "claims": [], "status": "finished"}
        for n in layout
    ]
    sweep.write_index(root, {"suite": "mygrid", "jobs": jobs})
    return root


def test_labels_are_derived_from_the_config(suite):
    table = runs.load_table(suite)
    by_name = {r.name: r for r in table.records}
    plugin = by_name["mygrid/er21_lio_plugin"]
    assert plugin.condition == "plugin_attack_sneaky(strength=3)"
    assert plugin.env == "ER(2,1)" and plugin.defenses == "none"
    assert by_name["mygrid/maze_lio_clean"].env == "CM(2,1)"
    assert by_name["mygrid/er21_lio_clean_tripwire"].defenses == "tripwire(sensitivity=2)"
    assert table.clean_for(plugin).name == "mygrid/er21_lio_clean"
    colors = table.colors
    assert list(colors) == ["clean", "plugin_attack_sneaky(strength=3)"]  # clean first
    assert runs.env_label("foo-v0", {"size": 7}) == "FOO(size=7)"
    assert runs.env_label("stag_hunt-v0", {"n_players": 3, "max_steps": 50}) == "SH(3)"
    assert runs.condition_label("admo", {"mode": "disrupt", "lr": 1e-3}) == "admo_disrupt"
    assert sorted(["zeta", "bypass", "clean"], key=runs.condition_key) == [
        "clean",
        "bypass",
        "zeta",
    ]


def test_report_on_unknown_attack_env_and_defense(suite, tmp_path):
    out = report.write_report(suite, tmp_path / "report")
    markdown = (out / report.MARKDOWN).read_text()
    assert "## Attacks on LIO (C1–C5)" in markdown  # a paper section with an unknown attack
    assert "| ER(2,1) | plugin_attack_sneaky(strength=3) |" in markdown
    assert "## Other training runs" in markdown  # the generic section for the user's group
    generic = markdown.split("## Other training runs", 1)[1]
    assert "mygrid: 4 run(s)" in generic
    assert "| CM(2,1) | lio | none | clean |" in generic
    assert "| tripwire(sensitivity=2) | clean |" in generic
    row = next(line for line in generic.splitlines() if "| er21_lio_plugin |" in line)
    assert row.count("(range ") == 4  # success, margin, both effects vs clean: 2 seeds, ranges
    assert (out / report.FIGURES / "mygrid_success.png").exists()
    assert (out / report.TABLES / "mygrid.csv").exists()
    assert "attacks/" not in generic
    # A sweep directory (not `pimbot reproduce`'s suite) is judged against no claims.
    assert markdown.startswith("# pimbot: sweep report") and "## Claims" not in markdown
