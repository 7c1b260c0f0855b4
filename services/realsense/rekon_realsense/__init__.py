"""rekon-realsense: an Intel RealSense camera (or its .bag recording) as a rekon
frame source, through Intel's own SDK (pyrealsense2). The same shape as the C++
services: config (config/default.yaml with --config and --set laid over it),
heartbeats, shutdown, live STATS and <out>/realsense_stats.json."""
