"""Lens analysis: paraxial and cardinal data, spots, aberrations, wavefront/Zernike, diffraction
PSF/MTF, the report; figures in :mod:`.plot` (styled by :mod:`.style`)."""
