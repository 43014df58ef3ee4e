"""Simulation: scenarios and flights, the radar, episode drawing, recorded ADS-B flights, the scenario catalogue,
the motion model and the packed look layout. May import radar_env.common only (no filters, envs, gymnasium, torch)."""
