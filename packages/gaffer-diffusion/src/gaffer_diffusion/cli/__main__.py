"""`python -m gaffer_diffusion.cli ...` (as `accelerate launch -m gaffer_diffusion.cli train`)."""

import sys

from gaffer_diffusion.cli import main

sys.exit(main())
