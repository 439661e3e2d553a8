"""Images: target detection and the disk targets' eccentricity through the port."""
