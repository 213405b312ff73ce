"""The ROS 2 nodes: thin shells over fpp_nodes.core. Importing this package imports rclpy."""
