"""Fringe projection profilometry for ROS 2. The science lives in fpp_nodes.core and imports without rclpy."""
