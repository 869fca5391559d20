"""Point clouds out of graphcal: file formats (LAS/LAZ, PLY, 3DTK) and cloud-to-cloud distances."""
