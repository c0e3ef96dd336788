"""The phone kit's server side: the link and QR code a therapist gives the patient."""
