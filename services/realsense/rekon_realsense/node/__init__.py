"""rekon-realsense's node: the bus wiring (LCM, heartbeats, stats, the live
outlet) around the library one folder up, which knows nothing of LCM."""
