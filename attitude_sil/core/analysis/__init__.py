"""Analysis of runs: step and tracking metrics, on whole trajectories and one sample at a time (the compiled
pieces every driver shares). Imports the plant (quaternions) and the core root."""
