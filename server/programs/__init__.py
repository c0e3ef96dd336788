"""Exercise programs (``docs/programs.md``): the catalogue, prescriptions per patient in
versions, what the sessions did of them (adherence, progress, flags) and the program as
FHIR R4."""
