"""secure3d.reactive"""
