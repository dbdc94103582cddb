"""Recording I/O: rosbag2 reader/writer, CSV import and its presets, one ``load_recording``."""
