"""Simulation: scenarios, trajectories, the parts of the loop, the loop, results and metrics."""
