"""secure3d.mapping"""
