"""Suites of training runs: job kinds (`jobs`), user grids (`grid`), the paper's suite
(`presets`) and the engine that runs them locally or on Ray (`sweep`)."""
