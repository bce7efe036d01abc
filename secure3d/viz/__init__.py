"""secure3d.viz"""
