"""Replay measured airborne pulses over a voxel scene and score them against the measurement."""
