"""ROS 2 adapters: parse messages, call the pure core, publish. Only this package imports rclpy."""
