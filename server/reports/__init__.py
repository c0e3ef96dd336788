"""Session reports and exports: what the therapist files, sends and compares.

* ``content``  — the report as pydantic models (the OpenAPI schema) and how it is computed
  from a stored session: range of motion, exercises and repetitions, smoothness;
* ``quality``  — data quality: sensors, rates, lost samples, magnetometer disturbances;
* ``csv``      — the summary as CSV;
* ``pdf``      — a filed PDF (matplotlib);
* ``opensim``  — ``.mot`` joint angles (Rajagopal coordinates) and OpenSense ``.sto``;
* ``fhir``     — FHIR R4 Observations in a DiagnosticReport;
* ``progress`` — the metrics across a patient's sessions, with a trend;
* ``targets``  — the therapist's target range per joint and patient.
"""
