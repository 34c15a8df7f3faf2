"""ROS 2 sees the arm: ``jara-arm ros2`` publishes each arm as rmw_zenoh does (``rmw.py``), with messages
built by rosbags (``messages.py``); ``bridge.py`` is the process."""
