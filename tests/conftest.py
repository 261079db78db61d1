import os
import tempfile

# rcl writes logs to ~/.ros by default; keep test runs self-contained
os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="eha-ros-log-"))
