"""The `valve-sim` command line: the entry (cli) and one module per subcommand.

Each subcommand module has add_arguments(parser) and run(args) -> exit code.
May import: every other wing. Commands that drive nodes (demo) may use rclpy.
"""
