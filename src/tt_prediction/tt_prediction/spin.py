"""Running a node as its own process (`ros2 run`): start-up, spin and a clean shutdown, in one
place for every tt node (ROS glue)."""

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor


def spin_node(make_node, args=None, on_exit=None):
    """Run the node that ``make_node()`` returns until SIGINT or SIGTERM, then shut down
    cleanly: the node destroyed, the context shut down, exit status 0 and no traceback.

    The executor exists before the node, because a signal may come while the node starts
    (compiling its kernels, say); a failure after a signal has shut the context down is the
    shutdown, not an error. ``on_exit(node)`` runs before the node is destroyed.
    """
    rclpy.init(args=args)
    executor = SingleThreadedExecutor()
    node = None
    try:
        node = make_node()
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        if rclpy.ok():
            raise
    finally:
        executor.shutdown()
        if node is not None:
            if on_exit is not None:
                on_exit(node)
            node.destroy_node()
        rclpy.try_shutdown()
