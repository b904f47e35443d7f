"""Report sections: one provider per part of the paper, and a generic one for other runs."""
