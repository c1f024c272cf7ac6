"""Scenario suites, rollouts, planners and diversity metrics (installed as feat2map.scenarios)."""
