"""Log I/O: numpy column chunks in and out of rosbag2 (sqlite3/mcap) and bare MCAP files."""
