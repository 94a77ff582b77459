"""Docker/Podman engine access and the images espdock keys, caches, bootstraps and prunes."""
