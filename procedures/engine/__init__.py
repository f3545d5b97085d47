"""The procedure engine: runs a plan of steps and brings the bench to a safe state at its
end."""
