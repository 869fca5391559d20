"""Importers: real data formats -> the recording format (graphcal-recording/1) or its parts.

One module per format: velodyne_pcap (pcap captures), velodyne_calibration (db.xml / ROS YAML
-> SensorModel), kitti (KITTI raw drives), sbet (Applanix SBET -> Trajectory), trajectory_csv
(user CSV -> Trajectory). docs/howto/import.md describes each.
"""
