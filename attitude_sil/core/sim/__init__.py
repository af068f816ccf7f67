"""The simulation: parameter schema and files, scenarios, lockstep rules, the engine and its drivers (stepwise
and the compiled batch loop). The top of core: it imports plant, control and analysis."""
