"""ahrsd.simulation"""
