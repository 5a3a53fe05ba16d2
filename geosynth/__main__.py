import sys

from geosynth.cli import main

sys.exit(main())
