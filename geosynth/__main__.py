"""How is geosynth run as ``python -m geosynth``? Through the command line, with
interrupts caught from the first instant (:mod:`geosynth._launch`).

Implements no paper section.
"""

import sys

from geosynth._launch import main

sys.exit(main())
