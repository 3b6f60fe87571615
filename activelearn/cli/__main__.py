"""`python -m activelearn.cli`: the `activelearn` console script."""

from activelearn.cli import main

raise SystemExit(main())
