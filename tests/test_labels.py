"""Run labels of `pimbot table` and `pimbot plot` tell runs apart by what they ran with."""

from __future__ import annotations

import json

from pimbot.analysis.runs import run_label


def _run_dir(tmp_path, name, defenses):
    run = tmp_path / name
    run.mkdir()
    config = {
        "identity": {
            "learner": "lio",
            "attack": "bypass",
            "attack_params": {},
            "first_seed": 0,
            "seeds": 2,
        },
        "env": {"id": "escape_room-v0", "params": {"n_agents": 2, "min_at_lever": 1}},
        "run_config": {"attack_params": [], "defenses": defenses},
    }
    (run / "config.json").write_text(json.dumps(config))
    return run


def test_a_label_names_the_defenses_a_run_trained_with(tmp_path):
    plain = run_label(_run_dir(tmp_path, "plain", []))
    guarded = run_label(_run_dir(tmp_path, "guarded", [["incentive_guard", []]]))
    both = [["incentive_guard", [["history", 16]]], ["health_monitor", []]]
    assert plain == "lio ER(2,1) bypass"
    assert guarded == "lio ER(2,1) bypass + incentive_guard"
    assert run_label(_run_dir(tmp_path, "both", both)) == (
        "lio ER(2,1) bypass + incentive_guard(history=16)+health_monitor"
    )
