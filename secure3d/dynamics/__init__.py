"""secure3d.dynamics"""
