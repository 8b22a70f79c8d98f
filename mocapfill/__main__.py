from mocapfill.cli import main

main()
