"""secure3d.simulation"""
