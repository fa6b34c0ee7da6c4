import sys

from pipelines.nordland import main

sys.exit(main())
