"""episcatter: Mitsuba 3 integrators for single scattering with volumetric shadows (god rays)."""
