from demos.cli import main

raise SystemExit(main())
