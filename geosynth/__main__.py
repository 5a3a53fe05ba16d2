"""How is geosynth run as ``python -m geosynth``? Through the command line.

Implements no paper section.
"""

import sys

from geosynth.cli import main

sys.exit(main())
