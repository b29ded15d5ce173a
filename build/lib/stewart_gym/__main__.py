from stewart_gym.cli import main

raise SystemExit(main())
