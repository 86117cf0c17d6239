"""Research tooling: training, closed-loop experiments in process, tables and figures for the
docs. These import the simulator and several stages at once, which no service may do
(tests/test_import_rules.py); the services never import them."""
