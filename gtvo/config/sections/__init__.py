"""The sections of a run's settings tree, one module per key of :class:`gtvo.config.OdometryConfig`.

Each module holds the frozen dataclasses of one section and imports only the settings core
(:mod:`gtvo.core.settings`) and, for the photometric model, :mod:`factors.params`: the settings are
a leaf of the house, so ``import gtvo.config`` loads no reader, front end, window, loop closing or
refinement (KISS-ICP's config module imports only its settings library). The components import
their section from here: the window its :class:`~gtvo.config.sections.window.WindowConfig`, the
tracker its :class:`~gtvo.config.sections.tracking.TrackingConfig`, and so on.

- :mod:`~gtvo.config.sections.solver`: ``solver``
- :mod:`~gtvo.config.sections.frontend`: ``frontend`` (point selection, stereo search)
- :mod:`~gtvo.config.sections.keyframes`: ``keyframes``
- :mod:`~gtvo.config.sections.tracking`: ``tracking``
- :mod:`~gtvo.config.sections.window`: ``window``
- :mod:`~gtvo.config.sections.flow_fallback`: ``flow_fallback``
- :mod:`~gtvo.config.sections.frame_checks`: ``frame_checks``
- :mod:`~gtvo.config.sections.motion`: ``motion_model``
- :mod:`~gtvo.config.sections.loops`: ``loops``
- :mod:`~gtvo.config.sections.wheel`: ``wheel`` (and the wheel readers' options)
- :mod:`~gtvo.config.sections.refine`: ``refine``

``photometric`` is :class:`factors.params.PhotometricConfig`, the factors' own parameter object.
"""
