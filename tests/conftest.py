import os
import tempfile

# rcl writes logs to ~/.ros by default; keep test runs self-contained
os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="eha-ros-log-"))

# DDS isolation: a domain of our own (not 0) so a test run never talks to another
# graph on the machine, and discovery stays on this host
os.environ.setdefault("ROS_DOMAIN_ID", str(101 + os.getpid() % 100))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


def pytest_configure(config):
    # `make test-fast` skips these, `make test-graph` runs only them (issue 18, item 7)
    config.addinivalue_line("markers", "graph: runs the node graph (rclpy nodes on executors, DDS, processes); "
                                       "slow and timing-sensitive")
