"""radar-track-gym: simulation, shared filter math and the RadarTrack-v0 Gymnasium environment."""
