"""Measurements on simulation results against experiments and analytic solutions."""
