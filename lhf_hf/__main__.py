import sys

from lhf_hf.cli.main import main

sys.exit(main())
