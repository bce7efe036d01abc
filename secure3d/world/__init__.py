"""secure3d.world"""
