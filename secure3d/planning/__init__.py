"""secure3d.planning"""
