"""Plots, animations and annotated frames. Reads results; never drives a simulation."""
