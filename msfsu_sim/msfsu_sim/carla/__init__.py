"""carla-ros-bridge recordings -> the stack's training and evaluation bags (`msfsu-import-carla`, ROS-free).

`recording` reads what the recording holds (pass 1), `frames` decides which messages make each sample and its
labels, `labels` maps CARLA's semantic tags to the paper's classes, `route` derives navigation commands from a
recorded route, `importer` writes the output bag (pass 2) and is the command line.
"""
