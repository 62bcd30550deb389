"""What a person reads on a terminal, for the commands and the benchmarks alike: text tables
(``table``: ``print_table``, ``table_lines``) and short durations (``durations``:
``duration_text``). Standard library only; imports nothing else of the project."""
