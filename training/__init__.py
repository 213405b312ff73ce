"""Training the single-shot networks: data sets from the simulator with multi-shot labels, the
paper's FCN / AEN / UNet, the training loop, evaluation and ONNX export. Needs torch; the ROS nodes
never import this package."""
