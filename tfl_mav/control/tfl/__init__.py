"""The transverse-feedback-linearizing law (paper §V, §VI): its math, its configuration, its
estimators and its tick."""
