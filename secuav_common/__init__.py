"""Small modules both services and the libraries may import: scenario schema, id and port plans."""
