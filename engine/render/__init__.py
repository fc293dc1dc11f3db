"""What the engine shows people and programs: a plan (``plan``) and what apply did (``result``)."""
