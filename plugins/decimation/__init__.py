"""Articulated decimation plugins ([S09] quartic and the baselines register here)."""
