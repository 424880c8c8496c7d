"""The top layer: the ``rhs-slam`` console command over rhs_env (sensing, scenes), slam and agents."""
