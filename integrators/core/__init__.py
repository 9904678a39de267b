"""What every plugin shares (DESIGN §4): the opaque frame constants
(:mod:`.opaque`), Mitsuba's light transport on the active variant
(:mod:`.light_transport`), the scene's parameters (:mod:`.scene_params`, the
only reader of Mitsuba objects), the camera capture and shadow maps
(:mod:`.capture`), the brute-force marchers (:mod:`.marching`,
:mod:`.hybrid_march` over :mod:`.shadow_volumes`), the integrator
properties (:mod:`.properties`), the film layers (:mod:`.film`) and the
error-budget machinery (:mod:`.quality_auto`).
"""
