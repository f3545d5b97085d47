"""The line's dashboard (`station line --db URL`): every station's runs in the central
database, with yields, Cpk, control charts and the certificates."""
