"""Gymnasium environments on feat2map maps (installed as feat2map.envs)."""
