"""Loading procedure and product files into a plan of steps: models, the steps: list, the old
section form, the plan."""
