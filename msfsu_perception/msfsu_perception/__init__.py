"""MSFSU network, preprocessing, training and the perception node."""
