from minirt.cli.app import main

main()
