"""Byte layouts we write ourselves: DDS (BC1) textures and the irradiance-grid stream."""
