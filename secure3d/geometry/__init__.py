"""secure3d.geometry"""
